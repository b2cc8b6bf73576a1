"""Object proposals from depth: on the real Kinect frame of LM-O (../shared/data/lmo-depth) and on rendered
depth of boxes on a table, an object alone, and an empty frame."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from index.data.bop import BopDataset
from index.geometry.sensor import SensorModel, plane_depth, support_plane
from service.detection.depth_segments import (
    VISIBLE_SHARE,
    Segment,
    depth_proposals,
    depth_scene,
    largest_visible,
)

LMO_DEPTH = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "lmo-depth"
K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
W, H = 640, 480


def _iou(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    w, h = min(a[2], b[2]) - max(a[0], b[0]), min(a[3], b[3]) - max(a[1], b[1])
    return (
        0.0
        if w <= 0 or h <= 0
        else w * h / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - w * h)
    )


def _project(p: np.ndarray) -> np.ndarray:
    q = K @ p
    return q[:2] / q[2]


def test_real_kinect_frame_proposes_every_visible_instance():
    if not (LMO_DEPTH / "models" / "models_info.json").is_file():
        pytest.skip(f"real depth not present at {LMO_DEPTH}")
    insts = list(BopDataset(LMO_DEPTH).instances(2))
    info = json.loads((LMO_DEPTH / "test" / "000002" / "scene_gt_info.json").read_text())["3"]
    depth = insts[0].load_depth()
    props = depth_proposals(depth, insts[0].K, limit=50)
    assert 20 <= len(props) <= 50  # a cluttered desk: many objects besides the annotated ones
    assert all(a.score >= b.score for a, b in zip(props, props[1:], strict=False))
    ranks = {}
    for inst in insts:
        if inst.visib_fract < 0.5:
            continue
        x, y, w, h = inst.bbox_visib
        side = max(info[inst.index]["bbox_obj"][2:])
        u, v = inst.centre_uv
        hits = [
            k
            for k, p in enumerate(props)
            if np.hypot(p.u - u, p.v - v) <= side / 4 and _iou(p.box, (x, y, x + w, y + h)) >= 0.5
        ]
        assert hits, f"object {inst.obj_id} not proposed"
        ranks[inst.obj_id] = hits[0]
        # the first hit's distance is the object centre's, to a few centimetres
        assert abs(props[hits[0]].distance_mm - np.linalg.norm(inst.t)) < 70, inst.obj_id
    assert len(ranks) == 6
    assert sum(r < 30 for r in ranks.values()) >= 5  # the default limit keeps five of the six


def _boxes_on_table(renderer) -> tuple[np.ndarray, list[np.ndarray]]:
    """Depth of two boxes standing on a table seen from 1 m at 40 deg down, through the sensor model, and
    the boxes' centres (camera frame, mm)."""
    # table: the xy plane of a frame looking down at it; boxes stand on it at z = 0
    tilt = np.deg2rad(40)
    R = np.array([[1, 0, 0], [0, -np.sin(tilt), -np.cos(tilt)], [0, np.cos(tilt), -np.sin(tilt)]])
    t = np.array([0.0, 0.0, 1000.0])
    n, d = support_plane(R, t, 0.0)
    table = plane_depth(K, n, d, (H, W))
    placed, centres = [], []
    for (x, y), extents in (((-150.0, 0.0), (100.0, 80.0, 120.0)), ((120.0, 60.0), (60.0, 60.0, 180.0))):
        box = trimesh.creation.box(extents=extents)
        centre_obj = np.array([x, y, extents[2] / 2])
        placed.append((box, R, R @ centre_obj + t))
        centres.append(R @ centre_obj + t)
    _, objects = renderer.render_frame(placed, K, W, H)
    clean = np.where(objects > 0, objects, table).astype(np.float32)
    _, depth = SensorModel().apply(None, clean, np.random.default_rng(0))
    return depth, centres


def test_two_boxes_on_a_table(renderer):
    depth, centres = _boxes_on_table(renderer)
    props = depth_proposals(depth, K)
    assert props
    near = [[p for p in props if np.hypot(*(np.array([p.u, p.v]) - _project(c))) < 20] for c in centres]
    for c, found in zip(centres, near, strict=True):
        assert found, "a box not proposed"
        assert abs(found[0].distance_mm - np.linalg.norm(c)) < 30
    # none on the bare table: every proposal's centre lies on one of the boxes
    for p in props:
        assert min(np.hypot(*(np.array([p.u, p.v]) - _project(c))) for c in centres) < 60, p
    assert props[0] in near[0] + near[1]


def test_an_object_in_front_of_nothing(renderer, l_shape):
    """No table, no background: the object itself, not a plane of it, is proposed."""
    R = trimesh.transformations.rotation_matrix(np.deg2rad(35), [1, 0.3, 0])[:3, :3]
    t = np.array([40.0, -20.0, 700.0])
    _, clean = renderer.render_frame([(l_shape, R, t)], K, W, H)
    _, depth = SensorModel().apply(None, clean, np.random.default_rng(1))
    props = depth_proposals(depth, K)
    assert 1 <= len(props) <= 3
    best = props[0]
    assert np.hypot(*(np.array([best.u, best.v]) - _project(t))) < 25
    assert abs(best.distance_mm - np.linalg.norm(t)) < 40
    ys, xs = np.nonzero(clean)
    assert _iou(best.box, (xs.min(), ys.min(), xs.max(), ys.max())) > 0.6


def test_empty_and_bad_frames():
    assert depth_proposals(np.zeros((H, W), np.float32), K) == []
    assert depth_proposals(np.full((H, W), np.nan, np.float32), K) == []
    assert depth_proposals(np.full((H, W), 1000.0, np.float32), K, limit=0) == []
    with pytest.raises(ValueError, match="depth"):
        depth_proposals(np.zeros((H, W, 3), np.float32), K)
    with pytest.raises(ValueError, match="K"):
        depth_proposals(np.zeros((H, W), np.float32), np.eye(2))
    with pytest.raises(ValueError, match="min_size_mm"):
        depth_proposals(np.zeros((H, W), np.float32), K, min_size_mm=300, max_size_mm=100)


def test_a_bare_wall_gives_no_proposal():
    """A flat wall facing the camera at 1.5 m is background, not an object."""
    z = plane_depth(K, np.array([0.0, 0.2, -1.0]) / np.linalg.norm([0.0, 0.2, -1.0]), -1500.0, (H, W))
    _, depth = SensorModel().apply(None, z, np.random.default_rng(2))
    assert depth_proposals(depth, K) == []


def test_proposal_fields_are_plain_floats():
    depth = np.zeros((H, W), np.float32)
    depth[200:260, 300:360] = 800.0
    (p,) = depth_proposals(depth, K)
    assert isinstance(p, Segment) and all(
        type(c) is float for c in (p.u, p.v, p.distance_mm, p.score, *p.box)
    )
    assert 300 <= p.u <= 360 and 200 <= p.v <= 260 and p.box == (300.0, 200.0, 359.0, 259.0)


def test_touching_objects_larger_than_any_registered_one_are_proposed_in_parts(renderer):
    """Three boxes standing side by side, touching, their fronts flush: one segment at every step level.
    Larger than any object looked for (`largest_mm`), it is also cut into parts, and each box is proposed;
    without knowing the objects' size, it is not (it is under two typical objects)."""
    tilt = np.deg2rad(40)
    R = np.array([[1, 0, 0], [0, -np.sin(tilt), -np.cos(tilt)], [0, np.cos(tilt), -np.sin(tilt)]])
    t = np.array([0.0, 0.0, 1000.0])
    n, d = support_plane(R, t, 0.0)
    table = plane_depth(K, n, d, (H, W))
    extents = (100.0, 80.0, 120.0)
    centres = [R @ np.array([x, 0.0, extents[2] / 2]) + t for x in (-100.0, 0.0, 100.0)]
    row = trimesh.creation.box(extents=(300.0, 80.0, 120.0))  # the three as one solid: no seam at all
    _, objects = renderer.render_frame([(row, R, centres[1])], K, W, H)
    depth = np.where(objects > 0, objects, table).astype(np.float32)
    _, depth = SensorModel().apply(None, depth, np.random.default_rng(3))
    diameter = float(np.linalg.norm(extents))

    corners = trimesh.creation.box(extents=extents).vertices
    boxes = []
    for c in centres:
        px = np.array([_project(R @ v + c) for v in corners])
        boxes.append((*px.min(axis=0), *px.max(axis=0)))

    def found(props: list[Segment]) -> list[bool]:
        """Whether each box has a proposal of its own: centred on it, over its extent."""
        return [
            any(np.hypot(*(np.array([p.u, p.v]) - _project(c))) < 15 and _iou(p.box, b) >= 0.4 for p in props)
            for c, b in zip(centres, boxes, strict=True)
        ]

    assert found(depth_proposals(depth, K)) == [False, False, False]  # the row alone, and fragments
    largest = largest_visible([diameter, 0.8 * diameter])
    assert largest == pytest.approx(VISIBLE_SHARE * diameter)
    assert found(depth_proposals(depth, K, largest_mm=largest)) == [True, True, True]
    assert largest_visible([]) is None


def test_a_pose_through_the_table_is_sunk(renderer):
    """Two boxes on a table: at their poses none of their surface lies below it; the first box moved 60 mm
    down through the table has a share of it there. Points the frame cannot show, beyond its edge or behind
    the camera, never count."""
    depth, centres = _boxes_on_table(renderer)
    scene = depth_scene(depth, K)
    support = scene.support
    assert support is not None
    # the table's normal (facing the camera) and the boxes' surfaces, sampled
    tilt = np.deg2rad(40)
    R = np.array([[1, 0, 0], [0, -np.sin(tilt), -np.cos(tilt)], [0, np.cos(tilt), -np.sin(tilt)]])
    assert abs(abs(support.plane.normal @ R[:, 2]) - 1) < 0.02
    surfaces = []
    for extents, centre in zip(((100.0, 80.0, 120.0), (60.0, 60.0, 180.0)), centres, strict=True):
        points = trimesh.creation.box(extents=extents).sample(2000, seed=0)
        surfaces.append(points @ R.T + centre)
        assert support.sunk(surfaces[-1]) <= 0.01
    down = -R[:, 2]
    sunk = support.sunk(surfaces[0] + 60.0 * down)
    assert 0.1 < sunk < 0.6, sunk
    assert support.sunk(surfaces[0] + 5.0 * down) <= 0.01  # the plane's own noise is no fault
    assert support.sunk(surfaces[0] + 60.0 * down + np.array([5000.0, 0, 0])) == 0.0  # beyond the frame
    assert support.sunk(-surfaces[0]) == 0.0  # behind the camera
    assert support.sunk(np.zeros((0, 3))) == 0.0


def test_a_frame_without_a_table_has_no_support(renderer, l_shape):
    R = trimesh.transformations.rotation_matrix(np.deg2rad(35), [1, 0.3, 0])[:3, :3]
    _, clean = renderer.render_frame([(l_shape, R, np.array([40.0, -20.0, 700.0]))], K, W, H)
    assert depth_scene(clean, K).support is None
    assert depth_scene(np.zeros((H, W), np.float32), K).support is None
