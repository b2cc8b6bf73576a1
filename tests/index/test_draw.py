"""The drawing of answers (`index.draw`) against the real renderer: the silhouette it fills is the one
pyrender renders at the same pose, the axes start where the origin projects."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from index.draw import (
    MAX_DRAW_FACES,
    PATCH_DRAW_PX,
    DrawMesh,
    Drawn,
    MeshCache,
    draw_answers,
    draw_axes,
    patch_view,
    silhouette,
)
from index.features.patches import PatchSpec
from index.geometry.pose import View, view_to_pose

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
W, H = 640, 480


def pose_at(view: View, uv: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    return view_to_pose(view, np.linalg.inv(K) @ np.array([uv[0], uv[1], 1.0]))


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


@pytest.mark.parametrize(
    "view,uv",
    [
        (View(40.0, 30.0, 0.0, 600.0), (380.0, 250.0)),
        (View(220.0, 20.0, -45.0, 450.0), (150.0, 330.0)),
        (View(310.0, 65.0, 30.0, 800.0), (620.0, 20.0)),  # partly outside the frame: clipped
    ],
)
def test_silhouette_is_the_rendered_one(renderer, l_shape, view, uv):
    R, t = pose_at(view, uv)
    _, depth = renderer.render_frame([(l_shape, R, t)], K, W, H)
    drawn = silhouette(DrawMesh.of(l_shape), R, t, K, (H, W)) > 0
    rendered = depth > 0
    assert rendered.sum() > 500
    assert iou(drawn, rendered) >= 0.9


def test_a_heavy_mesh_is_cut_to_the_face_cap_and_keeps_its_silhouette():
    sphere = trimesh.creation.icosphere(subdivisions=6, radius=60.0)  # 81,920 faces
    light = DrawMesh.of(sphere)
    assert len(light.faces) <= MAX_DRAW_FACES < len(sphere.faces)
    R, t = pose_at(View(10.0, 40.0, 0.0, 500.0), (300.0, 200.0))
    full = silhouette(DrawMesh.of(sphere, max_faces=len(sphere.faces)), R, t, K, (H, W)) > 0
    assert iou(silhouette(light, R, t, K, (H, W)) > 0, full) >= 0.97


def test_axes_start_where_the_origin_projects(l_shape):
    R, t = pose_at(View(40.0, 30.0, 10.0, 600.0), (380.0, 250.0))
    image = np.zeros((H, W, 3), np.uint8)
    origin = draw_axes(image, R, t, K, 60.0)
    expected = (K @ t)[:2] / t[2]
    assert origin == (round(expected[0]), round(expected[1])) == (380, 250)
    assert (image[250, 380] == 255).all()  # the origin's white dot
    # the x axis is red, going where the model's +x projects
    x_end = K @ (R @ [60.0, 0, 0] + t)
    px = np.round(x_end[:2] / x_end[2]).astype(int)
    mid = ((px + [380, 250]) / 2).round().astype(int)
    assert image[mid[1], mid[0], 0] > 150 and image[mid[1], mid[0], 2] < 100


def test_answers_change_the_image_on_the_object_only(l_shape):
    R, t = pose_at(View(40.0, 30.0, 0.0, 600.0), (380.0, 250.0))
    mesh = DrawMesh.of(l_shape)
    image = np.full((H, W, 3), 90, np.uint8)
    out = draw_answers(image, [(mesh, Drawn("ell", 0.87, R, t))], K)
    changed = (out != image).any(axis=2)
    mask = silhouette(mesh, R, t, K, (H, W)) > 0
    assert changed[mask].mean() > 0.95  # tinted
    ys, xs = np.nonzero(mask)
    far = np.ones_like(changed)
    # the axes' ends within half a diameter of the silhouette, the label (~120 px long) just above it
    far[max(0, ys.min() - 70) : ys.max() + 70, max(0, xs.min() - 70) : max(xs.max(), xs.min() + 130) + 70] = (
        False
    )
    assert not changed[far].any()
    assert out is not image and (image == 90).all()


def test_behind_the_camera_draws_nothing(l_shape):
    R, t = pose_at(View(40.0, 30.0, 0.0, 600.0), (380.0, 250.0))
    image = np.full((H, W, 3), 90, np.uint8)
    out = draw_answers(image, [(DrawMesh.of(l_shape), Drawn("ell", None, R, -t))], K)
    assert (out == image).all()


def test_a_rejected_answer_is_grey_and_unknown(l_shape):
    R, t = pose_at(View(40.0, 30.0, 0.0, 600.0), (380.0, 250.0))
    assert Drawn("ell", 0.12, R, t, rejected=True).label == "unknown? ell  conf 0.12"
    assert Drawn("ell", 0.87, R, t).label == "ell  conf 0.87" and Drawn("ell", None, R, t).label == "ell"
    mesh = DrawMesh.of(l_shape)
    image = np.zeros((H, W, 3), np.uint8)
    out = draw_answers(image, [(mesh, Drawn("ell", 0.12, R, t, rejected=True))], K)
    inside = silhouette(mesh, R, t, K, (H, W)) > 0
    inside = inside & (np.abs(out.astype(int) - out[..., :1]).max(axis=2) == 0)  # grey, off the axes
    assert inside.sum() > 500


def test_patch_view_puts_the_origin_at_the_patch_centre(l_shape):
    spec = PatchSpec()
    big, Kp = patch_view(np.zeros((64, 64, 3), np.uint8), spec, 400.0)
    assert big.shape == (PATCH_DRAW_PX, PATCH_DRAW_PX, 3)
    R, t = view_to_pose(View(40.0, 30.0, 0.0, 400.0), np.array([0.0, 0.0, 1.0]))
    uv = (Kp @ t)[:2] / t[2]
    assert uv == pytest.approx([(PATCH_DRAW_PX - 1) / 2] * 2)
    # the window spans the whole drawing at the patch's distance
    edge = Kp @ np.array([spec.window_mm / 2, 0.0, 400.0])
    assert edge[0] / edge[2] == pytest.approx(PATCH_DRAW_PX - 0.5, abs=1e-6)


def test_mesh_cache_loads_once_and_forgets_the_deleted(l_shape):
    loads: list[int] = []

    def load(oid: int) -> DrawMesh | None:
        loads.append(oid)
        return DrawMesh.of(l_shape) if oid == 1 else None

    cache = MeshCache(load, capacity=2)
    assert cache.get(1) is cache.get(1) and loads == [1]
    assert cache.get(2) is None
    cache.prune({2})
    assert 1 not in cache and 2 in cache
    cache.get(3), cache.get(4)  # over capacity: the least recent goes
    assert 2 not in cache and loads == [1, 2, 3, 4]


def test_a_registered_mesh_draws_as_its_stored_glb(l_shape):
    """`DrawMesh.as_stored` (what the service keeps of a mesh it registers, without the GLB's round trip)
    is what the store's GLB gives back: float32 vertices, the same faces, with vertex or face colours."""
    faced = trimesh.creation.icosphere(subdivisions=3, radius=40.0)
    colours = np.random.default_rng(0).integers(0, 255, (len(faced.faces), 4))
    faced.visual = trimesh.visual.ColorVisuals(faced, face_colors=colours)
    for mesh in (l_shape, faced):
        mesh = mesh.copy()
        mesh.vertices += 1e-4 / 3  # not float32 numbers
        glb = mesh.export(file_type="glb")
        a, b = DrawMesh.from_glb(glb), DrawMesh.as_stored(mesh)
        assert a is not None
        np.testing.assert_array_equal(a.vertices, b.vertices)
        np.testing.assert_array_equal(a.faces, b.faces)
        assert a.diameter == b.diameter


def test_mesh_cache_keeps_what_it_is_given(l_shape):
    cache = MeshCache(lambda oid: pytest.fail("loaded"), capacity=2)
    given = DrawMesh.of(l_shape)
    cache.put(1, given)
    assert cache.get(1) is given
    cache.put(2, None), cache.put(3, None)  # over capacity: the least recent goes
    assert 1 not in cache and 3 in cache
