"""The paper's metric on hand-made poses: symmetric objects, a wrong object = 180°, the k = 1…22 table,
"within t°" strictly below t."""

import numpy as np
import pytest

from evaluation.paper.metric import K_MAX, Poses, accuracy, neighbour_errors, pose_errors, same_object
from index.geometry.pose import View, view_to_pose
from index.geometry.pose_error import rotation_error, view_error


def errors_of(template_views, sample_view, symmetry, protocol):
    return pose_errors(Poses.of(template_views), Poses.of([sample_view]), symmetry, protocol)


def test_paper_protocol_is_the_angle_between_viewing_directions():
    gt = View(10, 30)
    err = errors_of([View(10, 30), View(10, 50), View(40, 30), View(10, 30, 90)], gt, "none", "paper")
    assert err[0] == pytest.approx(0, abs=1e-6)
    assert err[1] == pytest.approx(20, abs=1e-6)
    assert 25 < err[2] < 30  # 30° of azimuth at 30° elevation: a little less than 30° on the sphere
    assert err[3] == pytest.approx(0, abs=1e-6)  # in-plane does not count under the paper's protocol


def test_half_turn_symmetry_forgives_the_opposite_view():
    gt, opposite = View(10, 30), View(190, 30)
    assert errors_of([opposite], gt, "none", "paper")[0] == pytest.approx(120, abs=1e-6)
    assert errors_of([opposite], gt, "180", "paper")[0] == pytest.approx(0, abs=1e-6)
    assert errors_of([View(100, 30)], gt, "180", "paper")[0] > 60  # a quarter turn still counts
    assert errors_of([opposite], gt, "180", "full")[0] == pytest.approx(0, abs=1e-6)
    assert errors_of([View(190, 30, 15)], gt, "180", "full")[0] == pytest.approx(15, abs=1e-6)


def test_full_protocol_counts_in_plane():
    gt = View(10, 30, 20)
    assert errors_of([View(10, 30, 20)], gt, "none", "full")[0] == pytest.approx(0, abs=1e-5)
    assert errors_of([View(10, 30, -10)], gt, "none", "full")[0] == pytest.approx(30, abs=1e-6)
    # Rotation-invariant objects: only the object's z axis counts, so azimuth is free.
    assert errors_of([View(130, 30, 0)], View(10, 30, 0), "full", "full")[0] == pytest.approx(0, abs=1e-5)


def test_the_metric_is_the_one_pose_error():
    rng = np.random.default_rng(0)
    views = [View(rng.uniform(0, 360), rng.uniform(0, 90), rng.uniform(-180, 180)) for _ in range(40)]
    gt = views[0]
    for symmetry in ("none", "180", "full"):
        paper = errors_of(views, gt, symmetry, "paper")
        full = errors_of(views, gt, symmetry, "full")
        assert np.array_equal(full, errors_of(views, gt, symmetry, "service"))
        R_gt = view_to_pose(gt)[0]
        for v, p, f in zip(views, paper, full, strict=True):
            assert p == pytest.approx(
                view_error(v.azimuth, v.elevation, gt.azimuth, gt.elevation, symmetry), abs=1e-4
            )
            assert f == pytest.approx(rotation_error(view_to_pose(v)[0], R_gt, symmetry), abs=1e-3)


def test_wrong_object_counts_as_180_and_nothing_retrieved_as_wrong():
    template_obj = np.array([1, 1, 2])
    template_poses = Poses.of([View(0, 30), View(0, 60), View(0, 30)])
    sample_obj = np.array([1, 2])
    sample_poses = Poses.of([View(0, 35), View(0, 30)])
    neighbours = np.array([[2, 1, 0], [0, -1, 2]])
    err = neighbour_errors(
        neighbours, template_obj, template_poses, sample_obj, sample_poses, {1: "none", 2: "none"}, "paper"
    )
    np.testing.assert_allclose(err, [[180, 25, 5], [180, 180, 0]], atol=1e-6)
    same = same_object(neighbours, template_obj, sample_obj)
    assert same.tolist() == [[False, True, True], [False, False, True]]


def test_accuracy_table_on_known_errors():
    """Four patches; wrong object = 180. Best of k and recognition follow by hand."""
    errors = np.full((4, K_MAX), 180.0)
    same = np.zeros((4, K_MAX), bool)
    errors[0, 0], same[0, 0] = 3.0, True  # right at k = 1
    errors[1, 0], same[1, 0] = 30.0, True  # right object, 30° off; a better pose at k = 2
    errors[1, 1], same[1, 1] = 10.0, True
    errors[2, 21], same[2, 21] = 50.0, True  # the object appears only at k = 22, 50° off
    # patch 3: never the right object
    table = accuracy(errors, same)
    assert set(table) == {f"k{k}" for k in range(1, K_MAX + 1)}
    assert table["k1"] == {"5": 0.25, "20": 0.25, "40": 0.5, "180": 0.5}
    assert table["k2"] == {"5": 0.25, "20": 0.5, "40": 0.5, "180": 0.5}
    assert table["k22"] == {"5": 0.25, "20": 0.5, "40": 0.5, "180": 0.75}


def test_within_is_strictly_below_the_threshold():
    """A pose exactly 20° off is not within 20° (BOP's `<`); a hair less is."""
    errors = np.full((3, K_MAX), 180.0)
    same = np.zeros((3, K_MAX), bool)
    errors[:, 0], same[:, 0] = [20.0, np.nextafter(20.0, 0.0), 5.0], True
    k1 = accuracy(errors, same)["k1"]
    assert k1 == {"5": 0.0, "20": 2 / 3, "40": 1.0, "180": 1.0}
