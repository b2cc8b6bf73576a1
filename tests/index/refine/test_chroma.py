"""The colour check of a pose (`index.refine.chroma`) against the real renderer: an object rendered at a pose
agrees with itself there, not with the same shape in other colours, and a part hidden behind another is
not compared."""

from __future__ import annotations

import numpy as np
import trimesh

from index.geometry.pose import View, view_to_pose
from index.refine.chroma import MIN_POINTS, SurfaceColours, chroma_distance, visible
from index.templates.shapes import demo_shapes

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
W, H = 640, 480


def pose_at(view: View, uv: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    return view_to_pose(view, np.linalg.inv(K) @ np.array([uv[0], uv[1], 1.0]))


def painted(mesh: trimesh.Trimesh, rgb: tuple[int, int, int]) -> trimesh.Trimesh:
    """The same shape in one colour per half (so that it counts as coloured), the other half grey."""
    out = mesh.copy()
    colours = np.tile([*rgb, 255], (len(out.vertices), 1)).astype(np.uint8)
    colours[out.vertices[:, 0] < np.median(out.vertices[:, 0]), :3] = (128, 128, 128)
    out.visual = trimesh.visual.ColorVisuals(out, vertex_colors=colours)
    return out


def test_a_rendered_object_agrees_with_itself_and_not_with_its_shape_in_other_colours(renderer):
    mesh = demo_shapes()["robot"]
    R, t = pose_at(View(30.0, 35.0, 10.0, 550.0), (330.0, 250.0))
    rgb, depth = renderer.render_frame([(mesh, R, t)], K, W, H)
    background = np.full_like(rgb, 90)
    frame = np.where((depth > 0)[..., None], rgb, background)
    own = SurfaceColours.of(mesh)
    assert own is not None
    same = chroma_distance(frame, K, own, R, t)
    other = SurfaceColours.of(painted(mesh, (40, 200, 60)))
    assert other is not None
    wrong = chroma_distance(frame, K, other, R, t)
    assert same is not None and wrong is not None
    assert same < 0.15 < wrong
    assert wrong > 2 * same


def test_a_shape_without_colours_has_nothing_to_check():
    box = trimesh.creation.box((80.0, 60.0, 40.0))
    assert SurfaceColours.of(box) is None
    box.visual = trimesh.visual.ColorVisuals(box, vertex_colors=np.tile([150, 150, 150, 255], (8, 1)))
    assert SurfaceColours.of(box) is None  # one grey all over: a shape


def test_the_back_and_what_stands_behind_are_not_compared():
    box = painted(trimesh.creation.box((100.0, 100.0, 100.0)), (220, 30, 30))
    model = SurfaceColours.of(box, n=6000)
    assert model is not None
    R, t = np.eye(3), np.array([0.0, 0.0, 600.0])  # one face squarely towards the camera
    uv, idx = visible(model, R, t, K, (H, W))
    front = model.points[idx]
    assert len(idx) > MIN_POINTS
    assert np.all(front[:, 2] < -49.0)  # only the face at z = -50 (towards the camera) is seen
    assert len(idx) < 0.3 * len(model.points)


def test_a_pose_off_the_frame_or_behind_the_camera_measures_nothing():
    box = painted(trimesh.creation.box((100.0, 100.0, 100.0)), (220, 30, 30))
    model = SurfaceColours.of(box)
    assert model is not None
    frame = np.zeros((H, W, 3), np.uint8)
    assert chroma_distance(frame, K, model, np.eye(3), np.array([0.0, 0.0, -600.0])) is None
    assert chroma_distance(frame, K, model, np.eye(3), np.array([5000.0, 0.0, 600.0])) is None
    assert chroma_distance(frame[..., 0], K, model, np.eye(3), np.array([0.0, 0.0, 600.0])) is None
