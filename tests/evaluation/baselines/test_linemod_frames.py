"""LineMOD over whole frames: a rendered object found at its place, size, distance and pose among two
objects' templates; the pyramid's windows; non-maximum suppression."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.baselines.linemod_frames import LineModFrames, suppress, window_sizes
from index.geometry.boxes import iou
from index.geometry.pose import View, view_to_pose
from index.geometry.pose_error import rotation_error
from tests.evaluation.conftest import K, make_mug

VIEWS = [
    View(az, el, ip, 400.0) for az in (0.0, 90.0, 180.0, 270.0) for el in (30.0, 60.0) for ip in (0.0, 30.0)
]


def test_window_sizes():
    w = window_sizes(480)
    assert w[0] == 64.0 and w[-1] <= 480 < w[-1] * 2 ** (1 / 3)
    assert np.allclose(w[1:] / w[:-1], 2 ** (1 / 3))
    assert len(w) == 9  # 64 * 2^(8/3) = 406 px, the next (512) over 480
    assert window_sizes(40).tolist() == [64.0]


def test_suppress_keeps_the_best_of_overlapping_boxes():
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [20, 20, 30, 30], [0, 0, 10, 10]], float)
    assert suppress(boxes, np.array([0.5, 0.9, 0.7, 0.1]), 0.5, 10) == [1, 2]
    assert suppress(boxes, np.array([0.5, 0.9, 0.7, 0.1]), 0.5, 1) == [1]


def test_a_rendered_object_is_found_where_it_is(renderer, l_shape):
    lm = LineModFrames("rgb", renderer.window_mm, renderer.size)
    lm.add(1, renderer.render(l_shape, VIEWS))
    lm.add(2, renderer.render(make_mug(), VIEWS))
    window = 64 * 2 ** (2 / 3)  # one of the pyramid's windows: the object at f * 200 / window
    distance = (K[0, 0] + K[1, 1]) / 2 * renderer.window_mm / window
    true = View(90.0, 60.0, 30.0, distance)
    ray = np.array([0.1, -0.05, 1.0])
    R, t = view_to_pose(true, ray)
    rgb, depth = renderer.render_frame([(l_shape, R, t)], K, 640, 480)
    rgb = np.where(depth[..., None] > 0, rgb, 90).astype(np.uint8)
    ys, xs = np.nonzero(depth)
    box = (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1)

    hits = lm.detect((2, 0), rgb, None, K, window_sizes(480), max_detections=3)
    best = hits[0]
    assert best.obj_id == 1 and best.score > 0.9
    assert iou(best.box, box) > 0.7, (best.box, box)
    assert np.linalg.norm(best.t) == pytest.approx(distance, rel=0.02)
    assert np.degrees(np.arccos(best.t @ t / np.linalg.norm(best.t) / np.linalg.norm(t))) < 1.0
    assert rotation_error(best.R, R) < 10.0
    assert [h.score for h in hits] == sorted((h.score for h in hits), reverse=True)
