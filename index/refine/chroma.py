"""Whether a frame shows an object's colours where a pose puts it: the detection's check that needs no
training and holds for any registered object (`service.detection.agree`).

The recognition names the registered object nearest to what it sees, whatever it sees: with only objects
that are not in a frame registered, it still names one of them on each real object, as confidently as the
right object would be named (docs/experiments.md, issue 36). The mesh's own colours say otherwise: where the
pose puts the named object, the frame's pixels either have its colours or not.

`SurfaceColours.of(mesh)` is made once per object with colours: `POINTS` points spread over its surface by
area, each with its face's normal and its colour's chromaticity (r, g, b) / (r + g + b), which shading by
white light leaves as it is. `chroma_distance` puts them at the pose, keeps those facing the camera and
nearest in their `BIN_PX` cell of the frame (a z-buffer of points: a part behind another is not compared),
and gives the mean L1 distance between each kept point's chromaticity and the frame's at its pixel (0: the
same colours, up to 2). Occluders and the scene's light count against the right object too: the measure
ranks, it does not prove. Poses are BOP's (R, t model to camera, OpenCV axes, mm)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import trimesh

from index.geometry.shape_symmetry import textured

POINTS = 4000  # points on the surface: an object 100 px across keeps ~1000 after the z-buffer
BIN_PX = 2.0  # the z-buffer's cell (px)
HIDDEN_SHARE = 0.04  # a point this share of the diameter behind its cell's nearest is hidden by it
MIN_POINTS = 30  # fewer points seen than this: nothing measured
DARK = 30.0  # a pixel (or colour) whose channels sum under this has no chromaticity worth comparing (0-765)
BLUR_PX = 1.5  # the frame's chromaticity smoothed first: the Kinect's colour is noisy at edges


@dataclass(frozen=True)
class SurfaceColours:
    """Points on an object's surface (mm), their outward normals and their colours' chromaticity (N, 3)."""

    points: np.ndarray
    normals: np.ndarray
    chroma: np.ndarray
    diameter: float

    @classmethod
    def of(cls, mesh: trimesh.Trimesh, n: int = POINTS, seed: int = 0) -> SurfaceColours | None:
        """None for a mesh without colours that tell its sides apart (`textured`): a shape has none to check."""
        if not textured(mesh) or len(mesh.faces) == 0:
            return None
        visual: Any = mesh.visual
        if isinstance(visual, trimesh.visual.TextureVisuals):
            visual = visual.to_color()  # the texture sampled at each vertex
        if visual is None:
            return None
        if visual.kind == "face":
            face_rgb = np.asarray(visual.face_colors, np.float32)[:, :3]
            colour_at = None
        else:
            colour_at = np.asarray(visual.vertex_colors, np.float32)[:, :3]
            face_rgb = None
        rng = np.random.default_rng(seed)
        area = np.asarray(mesh.area_faces, float)
        if area.sum() <= 0:
            return None
        faces = rng.choice(len(area), size=n, p=area / area.sum())
        a, b = rng.random((2, n))
        flip = a + b > 1
        a[flip], b[flip] = 1 - a[flip], 1 - b[flip]
        w = np.stack([1 - a - b, a, b], axis=1)
        tri = np.asarray(mesh.vertices, float)[mesh.faces[faces]]  # (n, 3, 3)
        points = np.einsum("nk,nkd->nd", w, tri)
        if colour_at is not None:
            rgb = np.einsum("nk,nkd->nd", w, colour_at[mesh.faces[faces]])
        else:
            assert face_rgb is not None
            rgb = face_rgb[faces]
        normals = np.asarray(mesh.face_normals, float)[faces]
        return cls(
            points.astype(np.float32),
            normals.astype(np.float32),
            _chromaticity(rgb).astype(np.float32),
            float(np.ptp(points, axis=0).max() if len(points) else 0.0),
        )

    @property
    def nbytes(self) -> int:
        return self.points.nbytes + self.normals.nbytes + self.chroma.nbytes


def _chromaticity(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb, np.float32)
    s = rgb.sum(axis=-1, keepdims=True)
    return np.where(s > DARK, rgb / np.maximum(s, 1e-3), 1.0 / 3.0)


def visible(
    model: SurfaceColours, R: np.ndarray, t: np.ndarray, K: np.ndarray, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """The model's points seen at (R, t) in an image of `shape` (H, W): their pixels (M, 2) and indices (M,)."""
    R, t, K = np.asarray(R, float), np.ravel(np.asarray(t, float)), np.asarray(K, float)
    cam = model.points.astype(float) @ R.T + t
    z = cam[:, 2]
    facing = np.einsum("nd,nd->n", model.normals.astype(float) @ R.T, cam) < 0
    ok = facing & (z > 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (cam @ K.T)[:, :2] / z[:, None]
    h, w = shape
    ok &= np.isfinite(uv).all(axis=1) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0)
    ok &= uv[:, 1] <= h - 1
    idx = np.nonzero(ok)[0]
    if len(idx) == 0:
        return np.zeros((0, 2)), idx
    cells = np.floor(uv[idx] / BIN_PX).astype(np.int64)
    key = cells[:, 1] * (int(w / BIN_PX) + 2) + cells[:, 0]
    nearest = np.full(key.max() + 1, np.inf)
    np.minimum.at(nearest, key, z[idx])
    seen = z[idx] <= nearest[key] + HIDDEN_SHARE * max(model.diameter, 1.0)
    return uv[idx[seen]], idx[seen]


def chroma_distance(
    rgb: np.ndarray, K: np.ndarray, model: SurfaceColours, R: np.ndarray, t: np.ndarray
) -> float | None:
    """The mean L1 distance (0-2) between the object's chromaticity and the frame's where the pose (R, t)
    shows its surface in `rgb` (H, W, 3) uint8 (intrinsics `K`); None when under `MIN_POINTS` points show."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        return None
    uv, idx = visible(model, R, t, K, rgb.shape[:2])
    if len(idx) < MIN_POINTS:
        return None
    x0, y0 = np.floor(uv.min(axis=0)).astype(int) - 4
    x1, y1 = np.ceil(uv.max(axis=0)).astype(int) + 5
    x0, y0 = max(x0, 0), max(y0, 0)
    crop = cv2.GaussianBlur(
        rgb[y0 : min(y1, rgb.shape[0]), x0 : min(x1, rgb.shape[1])].astype(np.float32), (0, 0), BLUR_PX
    )
    px = np.clip(np.round(uv - [x0, y0]).astype(int), 0, [crop.shape[1] - 1, crop.shape[0] - 1])
    frame = _chromaticity(crop[px[:, 1], px[:, 0]])
    return float(np.abs(frame - model.chroma[idx]).sum(axis=1).mean())
