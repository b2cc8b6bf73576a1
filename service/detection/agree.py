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
The weight and the allowance are `COLOUR_WEIGHT` and `COLOUR_ALLOWANCE`.
Frames with depth are measured, not weighed: a detection from depth is reported on the model's open-set
verdict, not on a confidence, so `report.floors` puts a ceiling on the distance instead
(`Settings.detect_colour_ceiling`, chosen on RGB-D validation frames). A depth model's frame is not measured."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from index.refine.chroma import chroma_distance
from service.detection.found import Detection, Frame
from service.state import AppState

# A colour frame's detection confidence times exp(-COLOUR_WEIGHT * max(its colour distance -
# COLOUR_ALLOWANCE, 0)), reported at `Settings.detect_rgb_floor`. Chosen together on the validation frames, the
# most found with at most 0.2 false detections a frame where only objects absent from them are registered
# (docs/experiments.md): weight 8, allowance 0.15, floor 0.25 found 66.1 %, 90.5 % of what it reported right,
# 0.10 false a frame (unweighed at 0.4: 61.7 %, 92.2 %, 2.55). An experiment sets them in its own process.
#: how much a detection's confidence falls as the frame's colours at its pose differ from its object's (0:
#: not weighed, the colour frame then reported at `Settings.detect_floor`: `report.floors`)
COLOUR_WEIGHT = 8.0
#: a colour distance up to this costs a detection nothing (0-2)
COLOUR_ALLOWANCE = 0.15


@dataclass(frozen=True)
class Agree:
    """Each detection's colour distance; in a colour frame, its confidence times
    `exp(-weight * max(its colour distance - allowance, 0))` (`COLOUR_WEIGHT`, 0: not weighed;
    `COLOUR_ALLOWANCE`), most confident first. Reported at their own floor (`report.floors`)."""

    state: AppState
    weight: float
    allowance: float = 0.0
    name: str = "agree"

    @classmethod
    def build(cls, state: AppState) -> Agree:
        return cls(state, COLOUR_WEIGHT, COLOUR_ALLOWANCE)

    def __call__(self, frame: Frame) -> Frame:
        if frame.d.rgb is None or frame.d.modality == "depth" or not frame.detections:
            return frame
        if frame.d.depth is not None:  # measured, not weighed: `report.floors` puts a ceiling on it
            return replace(frame, detections=tuple(self.measure(frame, x) for x in frame.detections))
        if self.weight <= 0:
            return frame
        weighed = tuple(self.weigh(frame, x) for x in frame.detections)
        return replace(frame, detections=tuple(sorted(weighed, key=lambda x: -x.confidence)))

    def measure(self, frame: Frame, x: Detection) -> Detection:
        """`x` with its colour distance (unchanged without a measure: an object without colours)."""
        if not x.result.matches or frame.d.rgb is None:
            return x
        model = self.state.surfaces.get(x.result.matches[0].object_id)
        if model is None:
            return x
        R, t = x.result.pose(0)
        distance = chroma_distance(frame.d.rgb, frame.K, model, R, t)
        return x if distance is None else replace(x, colour_distance=distance)

    def weigh(self, frame: Frame, x: Detection) -> Detection:
        """`x` with its colour distance and its confidence weighed by it (unchanged without a measure)."""
        x = self.measure(frame, x)
        distance = x.colour_distance
        if distance is None:
            return x
        factor = float(np.exp(-self.weight * max(distance - self.allowance, 0.0)))
        return replace(x, confidence=x.confidence * factor)
