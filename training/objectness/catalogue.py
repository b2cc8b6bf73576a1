"""Objects nobody will ask for: the 1,000 procedural meshes of pybullet's `random_urdfs` and the project's
own procedural shapes, painted at random, for the objectness network to learn what "an object" is without
ever seeing one a user registers.

`pybullet` is a training-time dependency only (its wheel carries `pybullet_data`); the service never
imports this module. A `random_urdfs` object is a union of convex pieces about 0.1 units across; each is
loaded, scaled to a random diameter, and painted per piece: a plain colour, a procedural texture of
`index.templates.shapes`, or smooth colour noise.
"""

from __future__ import annotations

from contextlib import suppress
from pathlib import Path

import numpy as np
import trimesh

from index.templates.mesh import diameter
from index.templates.shapes import TEXTURES, _normalise, _paint, random_shape


def random_urdfs_dir() -> Path:
    """The folder of pybullet's 1,000 `random_urdfs` (one sub-folder each, `NNN/NNN.obj`)."""
    try:
        import pybullet_data  # noqa: PLC0415  # training-time only: the service never needs it
    except ImportError as e:  # pragma: no cover - the train extra installs it
        raise SystemExit("pybullet is not installed: `make setup` installs the training dependencies") from e
    return Path(pybullet_data.getDataPath()) / "random_urdfs"


def catalogue(root: Path | None = None) -> list[Path]:
    """The `.obj` files of `random_urdfs`, sorted (1,000 in pybullet 3.2.7)."""
    root = root or random_urdfs_dir()
    return sorted(root.glob("*/[0-9]*.obj"))


def _noise(mesh: trimesh.Trimesh, rng: np.random.Generator) -> trimesh.Trimesh:
    """Smooth three-channel colour noise (a few random sinusoids per channel) around a base colour."""
    v = mesh.vertices
    base = rng.uniform(30, 225, 3)
    rgb = np.empty((len(v), 3))
    for c in range(3):
        k = rng.normal(size=(3, 4)) / rng.uniform(10.0, 60.0)
        rgb[:, c] = base[c] + rng.uniform(10, 60) * np.sin(v @ k + rng.uniform(0, 2 * np.pi, 4)).mean(axis=1)
    colours = np.concatenate([np.clip(rgb, 0, 255), np.full((len(v), 1), 255.0)], axis=1).astype(np.uint8)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=colours)
    return mesh


def photo_paint(mesh: trimesh.Trimesh, photo: np.ndarray, rng: np.random.Generator) -> trimesh.Trimesh:
    """The mesh's vertices coloured from a photograph (H, W, 3) uint8 projected along a random axis and
    stretched over a random part of it: the colours and grain of real surfaces (wood, paper, cloth,
    print), not a render's flat paint."""
    v = mesh.vertices
    axes = np.linalg.qr(rng.normal(size=(3, 3)))[0][:, :2]
    uv = v @ axes
    uv = (uv - uv.min(axis=0)) / np.maximum(np.ptp(uv, axis=0), 1e-9)
    h, w = photo.shape[:2]
    side = rng.uniform(0.1, 0.5) * min(h, w)  # px of the photo across the object
    x0, y0 = rng.uniform(0, w - side), rng.uniform(0, h - side)
    cols = np.clip((x0 + uv[:, 0] * side).astype(int), 0, w - 1)
    rows = np.clip((y0 + uv[:, 1] * side).astype(int), 0, h - 1)
    rgb = photo[rows, cols].astype(np.float64)
    colours = np.concatenate([rgb, np.full((len(v), 1), 255.0)], axis=1).astype(np.uint8)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=colours)
    return mesh


def load_painted(path: Path, rng: np.random.Generator, diameter_mm: tuple[float, float]) -> trimesh.Trimesh:
    """One `random_urdfs` mesh, its pieces subdivided (so that a texture shows) and painted, scaled to a
    random diameter in mm and centred on its bounding box."""
    loaded = trimesh.load(path, force="scene", process=False)
    assert isinstance(loaded, trimesh.Scene)  # force="scene"
    pieces = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    if not pieces:
        raise ValueError(f"{path}: no triangles")
    whole = trimesh.util.concatenate(pieces)
    assert isinstance(whole, trimesh.Trimesh)  # meshes concatenate to a mesh
    scale = 100.0 / max(float(np.ptp(whole.vertices, axis=0).max()), 1e-9)  # pieces ~100 mm across
    painted = []
    one = rng.random() < 0.35  # one paint for the whole object, else one per piece
    texture = str(rng.choice([*TEXTURES, "noise"]))
    for piece in pieces:
        piece = piece.copy()
        piece.apply_scale(scale)
        while len(piece.faces) < 400:
            piece = piece.subdivide()
        if not one:
            texture = str(rng.choice([*TEXTURES, "noise"]))
        painted.append(_noise(piece, rng) if texture == "noise" else _paint(piece, rng, texture))
    mesh = trimesh.util.concatenate(painted)
    assert isinstance(mesh, trimesh.Trimesh)
    if diameter(mesh) <= 1e-6:
        raise ValueError(f"{path}: a degenerate mesh (no extent)")
    return _normalise(mesh, float(rng.uniform(*diameter_mm)))


def catalogue_object(
    paths: list[Path],
    index: int,
    rng: np.random.Generator,
    diameter_mm: tuple[float, float] = (40.0, 300.0),
    photos: list[np.ndarray] | None = None,
    photo_share: float = 0.5,
) -> trimesh.Trimesh:
    """Object `index` of the catalogue: the `random_urdfs` mesh of that index, or past their end a
    procedural shape (`index.templates.shapes.random_shape`); with `photos`, `photo_share` of them
    coloured from one (`photo_paint`) instead of painted."""
    mesh = None
    if index < len(paths):
        with suppress(ValueError):  # a few of the 1,000 are degenerate: a procedural shape stands in
            mesh = load_painted(paths[index], rng, diameter_mm)
    if mesh is None:
        mesh = random_shape(rng, diameter_mm)
    if photos and rng.random() < photo_share:
        mesh = photo_paint(mesh, photos[int(rng.integers(len(photos)))], rng)
    return mesh
