"""Detection metrics on hand-made cases: matching, recall, precision, AP50, pose figures."""

import numpy as np
import pytest

from evaluation.detect.score import (
    FALSE,
    IGNORED,
    TRUE,
    Hit,
    Truth,
    average_precision,
    match,
    scores,
    xywh_box,
)
from index.geometry.boxes import iou
from index.geometry.pose import roll_rotation

F = (2, 0)  # scene 2, frame 0
T_GT = np.array([0.0, 0.0, 1000.0])


def truth(obj: int = 1, box=(100.0, 100.0, 200.0, 200.0), visib: float = 0.9, frame=F) -> Truth:
    return Truth(frame, obj, box, box, visib, np.eye(3), T_GT)


def hit(obj: int = 1, box=(100.0, 100.0, 200.0, 200.0), score: float = 0.9, R=None, t=None, frame=F) -> Hit:
    return Hit(frame, obj, score, box, R, t)


def shifted(overlap: float) -> tuple[float, float, float, float]:
    """A 100 x 100 box slid right of (100, 100, 200, 200) so that their IoU is `overlap`."""
    # IoU of two 100-wide boxes shifted by d: (100 - d) / (100 + d)
    d = 100.0 * (1 - overlap) / (1 + overlap)
    return (100.0 + d, 100.0, 200.0 + d, 200.0)


def test_boxes():
    assert xywh_box([10, 20, 30, 40]) == (10.0, 20.0, 40.0, 60.0)
    assert iou((0, 0, 10, 10), (0, 0, 10, 10)) == 1.0
    assert iou((0, 0, 10, 10), (10, 0, 20, 10)) == 0.0
    assert iou((0, 0, 10, 10), (5, 0, 15, 10)) == pytest.approx(50 / 150)
    assert iou(shifted(0.49), (100, 100, 200, 200)) == pytest.approx(0.49)


def test_a_perfect_hit():
    m = match([hit(R=np.eye(3), t=T_GT)], [truth()])
    assert m.outcome == [TRUE] and m.truth_of == [0]
    s = scores(m)["all"]
    assert s["recall"] == 1.0 and s["precision"] == 1.0 and s["ap50"] == 1.0
    assert s["rotation_within_20"] == 1.0 and s["median_relative_distance_error"] == 0.0


def test_a_wrong_object_is_a_false_positive_and_misses_the_target():
    m = match([hit(obj=2)], [truth(obj=1)])
    assert m.outcome == [FALSE]
    s = scores(m)
    assert s["all"]["recall"] == 0.0 and s["all"]["precision"] == 0.0 and s["all"]["ap50"] == 0.0
    assert s["per_object"]["2"]["false_positives"] == 1 and s["per_object"]["2"]["targets"] == 0
    assert s["per_object"]["1"]["targets"] == 1 and s["per_object"]["1"]["hits"] == 0


def test_iou_049_misses_051_finds():
    assert match([hit(box=shifted(0.49))], [truth()]).outcome == [FALSE]
    assert match([hit(box=shifted(0.51))], [truth()]).outcome == [TRUE]


def test_either_box_counts():
    """A hit on the whole box of a half-hidden object is right, though it overlaps its visible box little."""
    tr = Truth(F, 1, (100.0, 100.0, 150.0, 200.0), (100.0, 100.0, 200.0, 200.0), 0.6, np.eye(3), T_GT)
    assert match([hit(box=(100.0, 100.0, 200.0, 200.0))], [tr]).outcome == [TRUE]
    assert match([hit(box=(100.0, 100.0, 150.0, 200.0))], [tr]).outcome == [TRUE]


def test_a_low_visibility_instance_is_neither_target_nor_error():
    m = match([hit(), hit(score=0.5)], [truth(visib=0.3)])
    assert m.outcome == [IGNORED, IGNORED]
    s = scores(m)["all"]
    assert s["targets"] == 0 and s["hits"] == 0 and s["ignored"] == 2
    assert s["recall"] is None and s["precision"] is None and s["ap50"] is None


def test_two_hits_on_one_instance_are_one_true_and_one_false():
    m = match([hit(score=0.4), hit(score=0.8, box=(102.0, 100.0, 202.0, 200.0))], [truth()])
    assert [h.score for h in m.hits] == [0.8, 0.4]  # greedy by score: the more confident one finds it
    assert m.outcome == [TRUE, FALSE] and m.duplicate == [False, True]
    s = scores(m)["all"]
    assert s["recall"] == 1.0 and s["precision"] == 0.5 and s["ap50"] == 1.0 and s["duplicates"] == 1
    away = match([hit(score=0.8), hit(score=0.4, box=(400.0, 400.0, 450.0, 450.0))], [truth()])
    assert away.duplicate == [False, False] and scores(away)["all"]["duplicates"] == 0  # false, not twice


def test_hits_only_match_their_own_frame():
    assert match([hit(frame=(2, 1))], [truth(frame=(2, 0))]).outcome == [FALSE]


def test_average_precision_of_a_known_ranking():
    # 3 targets; ranking T F T F T: precisions 1, 1/2, 2/3, 2/4, 3/5 at recalls 1/3, 1/3, 2/3, 2/3, 1.
    # envelope at the recall steps: 1 (1/3), 2/3 (2/3), 3/5 (1) -> AP = (1 + 2/3 + 3/5) / 3
    ap = average_precision([True, False, True, False, True], 3)
    assert ap == pytest.approx((1 + 2 / 3 + 3 / 5) / 3)
    assert average_precision([True, True], 4) == pytest.approx(0.5)  # half the targets never found
    assert average_precision([], 2) == 0.0


def test_ap_pools_frames_and_objects_in_one_ranking():
    truths = [truth(obj=1), truth(obj=2, frame=(2, 1))]
    hits = [hit(obj=1, score=0.9), hit(obj=3, score=0.8), hit(obj=2, score=0.7, frame=(2, 1))]
    s = scores(match(hits, truths))
    assert s["all"]["ap50"] == pytest.approx((1 + 2 / 3) / 2)
    assert s["per_object"]["1"]["ap50"] == 1.0 and s["per_object"]["2"]["ap50"] == 1.0


def test_pose_figures_respect_symmetry_and_count_targets():
    turned = roll_rotation(180.0)  # a half turn about the camera's z axis: the object's z here
    hits = [hit(R=turned, t=T_GT * 1.04), hit(obj=2, R=np.eye(3), t=T_GT * 0.9)]
    truths = [truth(obj=1), truth(obj=2), truth(obj=3)]
    plain = scores(match(hits, truths))["all"]
    assert plain["rotation_within_20"] == pytest.approx(1 / 3)  # only object 2's pose is right
    assert plain["median_relative_distance_error"] == pytest.approx(0.07)  # of 0.04 and 0.10
    symmetric = scores(match(hits, truths), {1: "180"})["all"]
    assert symmetric["rotation_within_20"] == pytest.approx(2 / 3)
