"""Symmetry-aware pose similarity, in-plane included."""

import numpy as np
import pytest

from index.geometry.pose import View, view_to_pose
from index.geometry.pose_error import rotation_error
from training.similarity import closer, pose_distances, rotations


def R(az: float, el: float, ip: float = 0.0) -> np.ndarray:
    return view_to_pose(View(az, el, ip))[0]


def test_matches_rotation_error():
    rng = np.random.default_rng(0)
    views = [View(*rng.uniform([0, 0, -40], [360, 90, 40])) for _ in range(6)]
    Rs = rotations(views)
    for sym in ("none", "180", "full"):
        d = pose_distances(Rs, Rs[::-1], sym)
        for i in range(len(Rs)):
            for j in range(len(Rs)):
                assert d[i, j] == pytest.approx(rotation_error(Rs[i], Rs[::-1][j], sym), abs=1e-4)


def test_inplane_counts():
    d = pose_distances(R(30, 40, 10)[None], R(30, 40, 0)[None])[0, 0]
    assert d == pytest.approx(10.0, abs=1e-6)


def test_half_turn_symmetry():
    a, b = R(30, 40)[None], R(210, 40)[None]
    assert pose_distances(a, b, "none")[0, 0] > 100
    assert pose_distances(a, b, "180")[0, 0] == pytest.approx(0.0, abs=1e-4)
    assert pose_distances(a, R(120, 40)[None], "180")[0, 0] > 60


def test_full_symmetry_ignores_azimuth_not_elevation():
    assert pose_distances(R(0, 40)[None], R(137, 40)[None], "full")[0, 0] == pytest.approx(0.0, abs=1e-4)
    assert pose_distances(R(0, 40)[None], R(137, 60)[None], "full")[0, 0] == pytest.approx(20.0, abs=1e-4)
    # the in-plane turn tilts where the object's axis points in the image: it still counts
    assert pose_distances(R(0, 40, 15)[None], R(90, 40)[None], "full")[0, 0] > 5


def test_closer():
    assert closer(R(0, 30), R(10, 30), R(40, 30))
    assert not closer(R(0, 30), R(40, 30), R(10, 30))
    assert closer(R(0, 30), R(185, 30), R(40, 30), "180")
