"""The detection's support check (`Stand`): a pose that stands through the table is not an object there.

Objects stand on the table; they do not reach through it. In a frame with depth the detection knows the
plane its objects stand on (`depth_segments.Support`, from the frame's proposals), and each verified
detection's answer gives its object's surface at its pose (the depth refinement's points,
`index.refine.depth.DepthModel`). A detection whose surface lies deep below the plane where the frame shows
the plane in front of it (`Support.sunk`) names an object that cannot be where its pose says: it is dropped
before the merging, so that it cannot suppress a detection that stands.

The failure it answers is on real depth: an object nobody registered, lower than a registered one, is named
after it and its pose fitted to its top. On YCB-V's video 0000, a keyboard 30 mm high was named a cracker box
(60 mm thick at its thinnest) 34 times in 20 frames; fitted to the keys, the box's far side stood 37-780 mm
below the table. The right detections on the three videos stand at most 27 mm below the table found
(docs/experiments.md, "Poses through the table").

A detection without a fitted pose's surface (an object with no depth model) or a frame with no support found
passes. `SUNK_SHARE` is the share of the surface that may lie below (1: never dropped)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from service.detection.found import Detection, Frame
from service.state import AppState

#: the share of a detection's surface (at its pose) that may lie deeper below the frame's support than 2.5
#: times the plane's tolerance (30 mm at 1 m; `depth_segments.SUNK_TOLERANCE`). 0.01: every factor from 1.5
#: to 3.5 times the tolerance dropped 37-41 of YCB-V video 0000's 43 false detections and none of its 39 right
#: ones; at 0.05, 24-28 (docs/experiments.md, "Poses through the table"). An experiment sets it in its own
#: process (`scripts/rules_by_video.py`: 1, the check off)
SUNK_SHARE = 0.01


@dataclass(frozen=True)
class Stand:
    """The detections whose answered pose puts at most `share` of its object's surface through the frame's
    support (`depth_segments.Support.sunk`); the others are dropped."""

    state: AppState
    share: float
    name: str = "stand"

    @classmethod
    def build(cls, state: AppState) -> Stand:
        return cls(state, SUNK_SHARE)

    def __call__(self, frame: Frame) -> Frame:
        if frame.support is None or self.share >= 1 or not frame.detections:
            return frame
        return replace(frame, detections=tuple(x for x in frame.detections if self.stands(frame, x)))

    def stands(self, frame: Frame, x: Detection) -> bool:
        """Whether `x`'s best answer leaves its object above the frame's support (True without a surface to
        check: no answer, or an object without a depth model)."""
        if frame.support is None or not x.result.matches:
            return True
        model = self.state.shapes.depth.get(x.result.matches[0].object_id)
        if model is None:
            return True
        R, t = x.result.pose(0)
        surface = model.points @ np.asarray(R, float).T + np.ravel(t)
        return frame.support.sunk(surface) <= self.share
