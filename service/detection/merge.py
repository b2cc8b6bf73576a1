"""The detection's merging of duplicates: one instance found from several proposals is reported once.

Boxes overlapping by more than `iou` (intersection over union) are one object found twice, and the more
confident stays (non-maximum suppression)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from service.detection.found import Detection, Frame
from service.settings import Settings

#: 0.5 is the detection's own criterion (`posedesc evaluate --protocol detect`): two boxes that would both
#: count as the same instance cannot both be right.
NMS_IOU = 0.5


@dataclass(frozen=True)
class Merge:
    """Detections most confident first, each kept unless its box overlaps a kept one by more than `iou`."""

    iou: float = NMS_IOU
    name: str = "merge"

    @classmethod
    def build(cls, settings: Settings) -> Merge:
        return cls()

    def __call__(self, frame: Frame) -> Frame:
        ordered = sorted(frame.detections, key=lambda x: -x.confidence)
        return replace(frame, detections=tuple(suppress(ordered, self.iou)))


def iou(a: Sequence[float], b: Sequence[float]) -> float:
    """Intersection over union of two boxes (x0, y0, x1, y1)."""
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def suppress(ordered: Sequence[Detection], threshold: float = NMS_IOU) -> list[Detection]:
    """Non-maximum suppression: each detection (most confident first) kept unless its box overlaps a kept
    one by more than `threshold`."""
    kept: list[Detection] = []
    for x in ordered:
        if all(iou(x.box, k.box) <= threshold for k in kept):
            kept.append(x)
    return kept
