"""The detection's colour check (`Agree`): each detection in a colour frame weighed by how well the frame's
colours agree with its object's where its pose puts it (`index.refine.chroma`).

The verifier names the registered object nearest to what it sees, and a frame is full of objects nobody
registered: with only shapes absent from LM-O's frames registered, it named one of them on LM-O's objects
about as confidently as it names the right object (docs/experiments.md, issue 36). No training tells the
two apart for an object it never saw; the object's own colours do. A detection's confidence is multiplied by
`exp(-weight * max(distance - allowance, 0))`, the distance the mean L1 between the chromaticities of the object's visible
surface and of the frame there (0-2; a right detection's median 0.12 on the validation frames, a wrong
one's 0.29, an unregistered object's 0.36). An object without colours (a shape-only mesh) has none to
check: its detections keep their confidence (their names are already handicapped, `Settings.shape_handicap`).
Frames with depth are not weighed: their check is the depth fit (`report.reported`), and this one was
chosen on colour frames alone."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from index.refine.chroma import chroma_distance
from service.detection.found import Detection, Frame
from service.state import AppState


@dataclass(frozen=True)
class Agree:
    """Each colour-frame detection's confidence times `exp(-weight * max(its colour distance - allowance, 0))`
    (`Settings.detect_colour_weight`, 0: not weighed; `Settings.detect_colour_allowance`), most confident
    first. Reported at their own floor (`report.floors`)."""

    state: AppState
    weight: float
    allowance: float = 0.0
    name: str = "agree"

    @classmethod
    def build(cls, state: AppState) -> Agree:
        s = state.settings
        return cls(state, s.detect_colour_weight, s.detect_colour_allowance)

    def __call__(self, frame: Frame) -> Frame:
        if self.weight <= 0 or frame.d.rgb is None or frame.d.depth is not None or not frame.detections:
            return frame
        weighed = tuple(self.weigh(frame, x) for x in frame.detections)
        return replace(frame, detections=tuple(sorted(weighed, key=lambda x: -x.confidence)))

    def weigh(self, frame: Frame, x: Detection) -> Detection:
        """`x` with its colour distance and its confidence weighed by it (unchanged without a measure)."""
        if not x.result.matches:
            return x
        model = self.state.surfaces.get(x.result.matches[0].object_id)
        if model is None:
            return x
        R, t = x.result.pose(0)
        assert frame.d.rgb is not None
        distance = chroma_distance(frame.d.rgb, frame.K, model, R, t)
        if distance is None:
            return x
        factor = float(np.exp(-self.weight * max(distance - self.allowance, 0.0)))
        return replace(x, confidence=x.confidence * factor, colour_distance=distance)
