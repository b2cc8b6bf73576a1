"""The detection's merging of duplicates: one instance found from several proposals is reported once.

Boxes overlapping by more than `iou` (intersection over union) are one object found twice, and the more
confident stays (non-maximum suppression). So are two detections of one object whose origins lie nearer
than `SAME_PLACE` of its diameter, however their boxes overlap: two copies of a rigid object cannot stand
that close. On LM-O's RGB-D test frames the cat was found twice from two proposals, its boxes overlapping
by 0.497 and its origins 36 mm apart (its diameter 155 mm)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from index.geometry.boxes import iou
from index.templates.windows import object_diameter
from service.detection.found import Detection, Frame
from service.settings import Settings

#: 0.5 is the detection's own criterion (`posedesc evaluate --protocol detect`): two boxes that would both
#: count as the same instance cannot both be right.
NMS_IOU = 0.5
#: two detections of one object whose origins are nearer than this share of its diameter are one instance
#: (two copies side by side stand at least their smallest width apart: a quarter of the diameter or more
#: for objects no more elongated than 4 : 1)
SAME_PLACE = 0.25


@dataclass(frozen=True)
class Merge:
    """Detections most confident first, each kept unless its box overlaps a kept one by more than `iou` or it
    names a kept one's object nearer to it than `SAME_PLACE` of its diameter."""

    iou: float = NMS_IOU
    name: str = "merge"

    @classmethod
    def build(cls, settings: Settings) -> Merge:
        return cls()

    def __call__(self, frame: Frame) -> Frame:
        ordered = sorted(frame.detections, key=lambda x: -x.confidence)
        objects = frame.snapshot.objects
        diameters = {o: d for o, rec in objects.items() if (d := object_diameter(rec.extra)) is not None}
        return replace(frame, detections=tuple(suppress(ordered, self.iou, diameters)))


def suppress(
    ordered: Sequence[Detection], threshold: float = NMS_IOU, diameters: Mapping[int, float] | None = None
) -> list[Detection]:
    """Non-maximum suppression: each detection (most confident first) kept unless its box overlaps a kept
    one by more than `threshold`, or (`diameters`: mm by object id) it names a kept one's object with its
    origin nearer than `SAME_PLACE` of that diameter."""
    kept: list[Detection] = []
    for x in ordered:
        if all(iou(x.box, k.box) <= threshold and not same_place(x, k, diameters or {}) for k in kept):
            kept.append(x)
    return kept


def same_place(a: Detection, b: Detection, diameters: Mapping[int, float]) -> bool:
    """Whether `a` and `b` name one object (their best answers') with origins nearer than `SAME_PLACE` of its
    diameter (False without a diameter, or without answers)."""
    if not a.result.matches or not b.result.matches:
        return False
    obj = a.result.matches[0].object_id
    if obj != b.result.matches[0].object_id or obj not in diameters:
        return False
    gap = np.linalg.norm(np.ravel(a.result.pose(0)[1]) - np.ravel(b.result.pose(0)[1]))
    return bool(gap < SAME_PLACE * diameters[obj])
