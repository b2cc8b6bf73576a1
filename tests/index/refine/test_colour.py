"""The colour refinement (`index.refine.colour`) on a synthetic frame: a procedurally made, asymmetric mesh
(a block with a peg and a fin) filled at a known pose over a textured background. Its real data figures
are `scripts/fit_colour_eval.py`'s (in the history at 36ee81d)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import trimesh

from index.draw import DrawMesh, silhouette
from index.geometry.pose_error import rotation_error
from index.refine.colour import MODEL_PX, ColourModel, fit_colour, look_from
from index.refine.fit import apply_twist

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
H, W = 480, 640


def _mesh() -> trimesh.Trimesh:
    block = trimesh.creation.box(extents=(80.0, 50.0, 40.0))
    peg = trimesh.creation.cylinder(radius=12.0, height=50.0)
    peg.apply_translation((25.0, 0.0, 40.0))
    fin = trimesh.creation.box(extents=(20.0, 60.0, 10.0))
    fin.apply_translation((-40.0, 30.0, 0.0))
    return trimesh.util.concatenate([block, peg, fin])


@pytest.fixture(scope="module")
def scene() -> tuple[ColourModel, np.ndarray, np.ndarray, np.ndarray]:
    mesh = _mesh()
    R = apply_twist(np.diag([1.0, -1.0, -1.0]), np.zeros(3), np.array([0.5, 0.3, 0.4, 0, 0, 0]))[0]
    t = np.array([30.0, -20.0, 600.0])
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 140, (H, W, 3)).astype(np.uint8)
    rgb[..., 2] = 200  # a bluish, noisy background
    on = silhouette(DrawMesh.of(mesh), R, t, K, (H, W)) > 0
    rgb[on] = np.clip(rng.normal((210, 120, 40), 15, (int(on.sum()), 3)), 0, 255).astype(np.uint8)
    return ColourModel.of(mesh), rgb, R, t


def test_model_is_a_contour_per_view() -> None:
    model = ColourModel.of(DrawMesh.of(_mesh()), views=50, points=40)
    assert model.points.shape == (50, 40, 3) and model.normals.shape == (50, 40, 3)
    # each view's normals lie across its viewing direction, unit long
    n = model.normals.astype(float)
    assert np.abs(np.einsum("vpi,vi->vp", n, model.directions)).max() < 0.01
    assert np.allclose(np.linalg.norm(n, axis=2), 1.0, atol=0.01)
    # contour points lie on the mesh's outside: no farther out than its bounding sphere
    assert np.linalg.norm(model.points.astype(float), axis=2).max() <= model.diameter
    assert model.nbytes == model.directions.nbytes + model.coords.nbytes + model.angles.nbytes
    assert model.coords.itemsize == model.angles.itemsize == 1


def _reference_outline(
    mesh: DrawMesh, R: np.ndarray, scale: float, size: int
) -> tuple[np.ndarray, np.ndarray]:
    """The silhouette (size, size) uint8 and its outer contour's pixels (C, 2), every face filled on its
    own (`cv2.fillConvexPoly`), orthographic at `scale` px/mm with the origin in the middle."""
    uv = (mesh.vertices @ R.T)[:, :2] * scale + size / 2
    mask = np.zeros((size, size), np.uint8)
    for face in np.round(uv[mesh.faces] * 16).astype(np.int32):
        cv2.fillConvexPoly(mask, face, 255, lineType=cv2.LINE_8, shift=4)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return mask, np.concatenate(contours)[:, 0].astype(float)


def test_contours_agree_with_faces_filled_one_by_one() -> None:
    mesh = DrawMesh.of(_mesh())
    model = ColourModel.of(mesh, views=24, points=60)
    scale, size = MODEL_PX / mesh.diameter, 2 * MODEL_PX
    gaps, out, inside = [], [], []
    for v, d in enumerate(model.directions):
        R = look_from(d.astype(float))
        mask, contour = _reference_outline(mesh, R, scale, size)
        points, normals = model.view(v)
        uv = (points @ R.T)[:, :2] * scale + size / 2
        n2 = (normals @ R.T)[:, :2]
        gaps.append(np.linalg.norm(uv[:, None] - contour[None], axis=2).min(axis=1))
        ahead, behind = np.round(uv + 3 * n2).astype(int), np.round(uv - 3 * n2).astype(int)
        out.append(mask[ahead[:, 1], ahead[:, 0]] == 0)
        inside.append(mask[behind[:, 1], behind[:, 0]] > 0)
    # within a pixel of the outline the faces make (the reference fills the pixels an edge touches, the
    # model's outline runs between pixel centres), the normals pointing out of it
    gap = np.concatenate(gaps)
    assert gap.mean() < 1.0 and np.percentile(gap, 95) < 1.5 and gap.max() < 3.0
    assert np.mean(np.concatenate(out)) > 0.98 and np.mean(np.concatenate(inside)) > 0.98
    # each point's depth along its view within the mesh's (a contour pixel takes a vertex's depth)
    depth = np.einsum("vpi,vi->vp", model.points, -model.directions.astype(float))
    span = np.einsum("ni,vi->vn", mesh.vertices, -model.directions.astype(float))
    assert (depth >= span.min(axis=1, keepdims=True) - model.unit).all()
    assert (depth <= span.max(axis=1, keepdims=True) + model.unit).all()


def test_a_perturbed_start_comes_closer(scene: tuple) -> None:
    model, rgb, R, t = scene
    R0, t0 = apply_twist(R, t, np.array([0.05, -0.04, 0.06, 6.0, -4.0, 30.0]))  # ~5 deg, 5 % of the distance
    fit = fit_colour(rgb, K, model, R0, t0)
    assert fit.moved and fit.score > fit.start_score
    assert 0.0 <= fit.start_score <= fit.score <= 1.0
    # the outline pins the translation down (30 mm off to ~1); the rotation less so (5 deg to ~3: a
    # block's outline changes little as it turns a few degrees out of the image plane)
    assert rotation_error(fit.R, R) < 0.8 * rotation_error(R0, R)
    assert np.linalg.norm(fit.t - t) < 0.2 * np.linalg.norm(t0 - t)


def test_the_true_pose_stays(scene: tuple) -> None:
    model, rgb, R, t = scene
    fit = fit_colour(rgb, K, model, R, t)
    assert rotation_error(fit.R, R) < 2.0
    assert np.linalg.norm(fit.t - t) < 0.02 * t[2]


def test_a_mask_of_the_object_helps_or_keeps(scene: tuple) -> None:
    model, rgb, R, t = scene
    mask = silhouette(DrawMesh.of(_mesh()), R, t, K, (H, W)) > 0
    R0, t0 = apply_twist(R, t, np.array([-0.06, 0.03, 0.05, -5.0, 5.0, -30.0]))
    fit = fit_colour(rgb, K, model, R0, t0, mask=mask)
    assert rotation_error(fit.R, R) < rotation_error(R0, R)
    with pytest.raises(ValueError, match="mask"):
        fit_colour(rgb, K, model, R0, t0, mask=mask[:10])


@pytest.mark.parametrize(
    "frame,t",
    [
        (np.zeros((0, 0, 3), np.uint8), np.array([30.0, -20.0, 600.0])),  # an empty frame
        (np.full((H, W, 3), 90, np.uint8), np.array([30.0, -20.0, 600.0])),  # nothing to see
        (None, np.array([30.0, -20.0, -600.0])),  # behind the camera
        (None, np.array([5000.0, 0.0, 600.0])),  # off the frame
        (None, np.array([np.nan, 0.0, 600.0])),
    ],
)
def test_hopeless_starts_are_not_moved(scene: tuple, frame: np.ndarray | None, t: np.ndarray) -> None:
    model, rgb, R, _ = scene
    fit = fit_colour(rgb if frame is None else frame, K, model, R, t)
    assert not fit.moved
    assert np.array_equal(fit.R, R) and np.array_equal(fit.t, t, equal_nan=True)
