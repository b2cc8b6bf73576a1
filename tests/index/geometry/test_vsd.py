"""VSD (`index.geometry.pose_error.vsd`) on hand-made depth maps, and its render helper on the real renderer."""

import numpy as np
import pytest
import trimesh

from index.geometry.pose_error import VSD_DELTA, distance_map, render_depths, vsd

TAUS = [5.0, 20.0, 40.0]


def maps(value: float = 500.0) -> np.ndarray:
    """A 20x20 depth map (mm) with a 10x10 object in the middle at `value` mm."""
    d = np.zeros((20, 20))
    d[5:15, 5:15] = value
    return d


def test_equal_depths_have_zero_error():
    gt = maps()
    assert vsd(gt.copy(), gt, gt.copy(), VSD_DELTA, TAUS).tolist() == [0.0, 0.0, 0.0]


def test_an_occluded_region_does_not_count():
    """Half the object hides behind an occluder at 300 mm; there the estimate is 100 mm off, unseen."""
    gt, est, test = maps(), maps(), maps()
    est[5:15, 5:10] = 600.0
    test[5:15, 5:10] = 300.0
    assert vsd(est, gt, test, VSD_DELTA, TAUS).tolist() == [0.0, 0.0, 0.0]
    test[5:15, 5:10] = 500.0  # the occluder gone: half the object is 100 mm off
    assert vsd(est, gt, test, VSD_DELTA, TAUS).tolist() == [0.5, 0.5, 0.5]


def test_a_depth_gap_beyond_tau_is_wrong_and_within_tau_is_right():
    """The estimate 30 mm behind the truth: hidden behind the measured surface by its own mask, but it
    covers the truth's visible pixels, so they are compared (BOP's extension of the estimate's mask)."""
    gt = maps()
    assert vsd(maps(530.0), gt, gt.copy(), VSD_DELTA, TAUS).tolist() == [1.0, 1.0, 0.0]


def test_no_overlap_is_wholly_wrong_and_nothing_visible_too():
    gt, est = maps(), np.zeros((20, 20))
    est[0:4, 0:4] = 500.0
    assert vsd(est, gt, gt + est, VSD_DELTA, TAUS).tolist() == [1.0, 1.0, 1.0]
    empty = np.zeros((20, 20))
    assert vsd(empty, empty, empty, VSD_DELTA, TAUS).tolist() == [1.0, 1.0, 1.0]


def test_missing_sensor_depth_counts_as_visible():
    gt = maps()
    test = np.zeros((20, 20))  # the sensor saw nothing
    est = gt.copy()
    est[5:15, 5:10] = 600.0
    assert vsd(est, gt, test, VSD_DELTA, TAUS).tolist() == [0.5, 0.5, 0.5]


def test_with_K_depths_become_distances_from_the_camera_centre():
    K = np.array([[100.0, 0.0, 10.0], [0.0, 100.0, 10.0], [0.0, 0.0, 1.0]])
    d = distance_map(np.full((20, 20), 500.0), K)
    assert d[10, 10] == 500.0  # on the optical axis
    assert d[10, 0] == pytest.approx(500.0 * np.sqrt(1 + 0.1**2))
    gt = maps()
    assert vsd(gt.copy(), gt, gt.copy(), VSD_DELTA, TAUS, K).tolist() == [0.0, 0.0, 0.0]


def test_render_depths_feed_vsd(renderer):
    """A box 10 mm further than the truth: about 10 mm apart where both show (a bit more off-axis, as
    distances), so wrong at tau 5 and right at tau 20 on nearly every pixel."""
    K = np.array([[572.4, 0.0, 80.0], [0.0, 573.6, 60.0], [0.0, 0.0, 1.0]])
    box = trimesh.creation.box(extents=[80.0, 60.0, 40.0])
    Rg, tg = np.eye(3), np.array([0.0, 0.0, 600.0])
    depth_est, depth_gt = render_depths(renderer, box, K, 160, 120, Rg, tg + [0, 0, 10.0], Rg, tg)
    assert depth_gt.shape == (120, 160)
    assert depth_gt[60, 80] == pytest.approx(580.0, abs=0.5)  # the box's near face, 20 mm in front
    assert depth_est[60, 80] == pytest.approx(590.0, abs=0.5)
    errors = vsd(depth_est, depth_gt, depth_gt, VSD_DELTA, [5.0, 20.0], K)
    assert errors[0] > 0.9 and errors[1] < 0.1
    assert vsd(depth_gt, depth_gt, depth_gt, VSD_DELTA, [5.0], K)[0] == 0.0
