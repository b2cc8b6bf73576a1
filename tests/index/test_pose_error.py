"""The one pose error (`index.pose_error`): vectorised, symmetry-aware, and "within" strictly below."""

import numpy as np
import pytest

from index.pose import View, camera_centre, view_to_pose
from index.pose_error import rotation_error, rotation_errors, view_error, view_errors, within


def R(az: float, el: float, ip: float = 0.0, ray=None) -> np.ndarray:
    return view_to_pose(View(az, el, ip), ray)[0]


def test_rotation_errors_are_every_pair_of_the_one_pair_function():
    rng = np.random.default_rng(1)
    est = np.stack([R(*rng.uniform([0, 0, -180], [360, 90, 180])) for _ in range(5)])
    gt = np.stack([R(*rng.uniform([0, 0, -180], [360, 90, 180])) for _ in range(3)])
    for symmetry in ("none", "180", "full"):
        errors = rotation_errors(est, gt, symmetry)
        assert errors.shape == (5, 3)
        for i in range(5):
            for j in range(3):
                assert errors[i, j] == pytest.approx(rotation_error(est[i], gt[j], symmetry), abs=1e-9)


def test_rotation_error_counts_in_plane_and_forgives_symmetries():
    assert rotation_error(R(10, 30, 25), R(10, 30, -5)) == pytest.approx(30, abs=1e-6)
    assert rotation_error(R(190, 30), R(10, 30), "180") == pytest.approx(0, abs=1e-6)
    assert rotation_error(R(190, 30), R(10, 30)) > 100
    assert rotation_error(R(130, 30), R(10, 30), "full") == pytest.approx(0, abs=1e-5)
    assert rotation_error(R(130, 30, 20), R(10, 30), "full") > 5  # a roll still tilts the z axis


def test_view_errors_ignore_in_plane_on_any_ray():
    """Both poses on one off-axis ray (the service's answer along the ray through (u, v)): the error is
    the angle between the two camera centres, whatever the rolls."""
    ray = np.array([0.3, -0.2, 1.0])
    est = np.stack([R(40, 20, 70, ray), R(40, 50, -30, ray)])
    gt = R(40, 20, 0, ray)[None]
    errors = view_errors(est, gt, "none", ray)[:, 0]
    assert errors[0] == pytest.approx(0, abs=1e-5)
    expected = np.degrees(np.arccos(camera_centre(40, 50) @ camera_centre(40, 20)))
    assert errors[1] == pytest.approx(expected, abs=1e-5) and errors[1] == pytest.approx(30, abs=1e-5)
    assert view_error(40, 50, 40, 20) == pytest.approx(30, abs=1e-5)
    assert view_error(100, 50, 280, 50, "180") == pytest.approx(0, abs=1e-5)
    assert view_error(100, 50, 17, 20, "full") == pytest.approx(30, abs=1e-5)  # elevation only


def test_within_is_strictly_below():
    assert within(np.array([19.999, 20.0, 20.001]), 20).tolist() == [True, False, False]


def test_equal_poses_are_zero_not_nan():
    """A rotation's trace may come out a hair above 3 (cosine above 1): clipped before arccos."""
    rng = np.random.default_rng(2)
    for _ in range(50):
        r = R(*rng.uniform([0, 0, -180], [360, 90, 180]))
        for symmetry in ("none", "180", "full"):
            assert rotation_error(r, r, symmetry) == pytest.approx(0, abs=1e-5)
            assert view_errors(r, r, symmetry)[0, 0] == pytest.approx(0, abs=1e-5)
