"""`service.detection.merge`: one instance found twice is reported once, by its boxes' overlap or, for one
object, by how near its two origins are (the RGB-D test frames' cat: boxes overlapping by 0.497, origins
36 mm apart)."""

from __future__ import annotations

import numpy as np

from index.store import Match
from service.detection.found import Detection, Proposal
from service.detection.merge import SAME_PLACE, suppress
from service.pipeline.answer import Result

FOCAL, CX, CY = 572.0, 320.0, 240.0


def found(object_id: int, u: float, v: float, distance_mm: float, box, confidence: float) -> Detection:
    """A detection of `object_id` whose origin projects at (u, v), `distance_mm` from the camera."""
    ray = np.array([(u - CX) / FOCAL, (v - CY) / FOCAL, 1.0])
    ray /= np.linalg.norm(ray)
    match = Match(object_id, f"obj{object_id}", 30.0, 40.0, 0.0, 0.1)
    result = Result("rgbd", [match], {}, ray, distance_mm, confidences=[confidence], origins_mm=[distance_mm])
    return Detection(u, v, box, confidence, result, Proposal(u, v, None, box, 0.9, "depth"))


def test_one_object_twice_within_a_quarter_of_its_diameter_is_one_instance():
    first = found(6, 412.0, 201.0, 1100.0, (378.6, 166.4, 446.7, 236.5), 1.0)
    again = found(6, 398.0, 196.0, 1126.0, (375.9, 165.0, 420.0, 226.4), 0.49)  # IoU 0.497 with `first`
    gap = np.linalg.norm(first.result.pose(0)[1] - again.result.pose(0)[1])
    assert 20 < gap < SAME_PLACE * 155.0
    assert suppress([first, again], diameters={6: 155.0}) == [first]
    assert suppress([first, again]) == [first, again]  # no diameter known: the boxes alone decide
    # another object there is another instance; so is the same object a diameter away
    other = found(5, 398.0, 196.0, 1126.0, again.box, 0.49)
    assert suppress([first, other], diameters={5: 155.0, 6: 155.0}) == [first, other]
    beside = found(6, 560.0, 201.0, 1100.0, (526.0, 166.0, 594.0, 236.0), 0.49)
    assert suppress([first, beside], diameters={6: 155.0}) == [first, beside]
