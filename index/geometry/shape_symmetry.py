"""An object's symmetry found from its shape: what a mesh without colour looks like after a turn.

A shape-only mesh (a CAD file, YCB-Video's meshes) looks the same after any turn that maps its surface onto
itself: a box after a half-turn, a can after any turn about its axis. Nothing tells those poses apart in
depth, and in colour only the silhouette and shading, so the templates need only one of them and a pose
error must forgive them (`symmetry`). A textured object's colours break the symmetry of its shape: its
symmetry is "none" unless its owner says otherwise.

The test: points sampled on the surface, turned about the object's z axis (the axis the project's
symmetries are about, `symmetry.SYMMETRIES`), and the 99th percentile of their distances to the surface
(another sample of it) compared with the object's diameter: a high percentile, so that a small part that
breaks the symmetry (a mug's handle, a nozzle) counts. A turn is a symmetry when that stays within
`TOLERANCE` of the diameter: a scanned box's half-turn comes out at 2-6 % (its faces are not flat), an
object that is not symmetric at 10 % and more (LM-O's five, a mug, a banana); "full" when every one
of a set of turns (`CONTINUOUS_TURNS`, one of them not a fraction of the turn that a 2-, 3-, 4-, 5- or 6-fold
symmetry repeats on) is. Measured on LM-O's and YCB-Video's meshes: docs/experiments.md, "Shape-only meshes".
Deterministic (seeded sampling), under a second for YCB-Video's meshes. The tolerance is a share of the whole
diameter: a long thin bar of square section (turned, its corners move little against its length) is taken
as round ("full").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

#: a turn is a symmetry when the `QUANTILE` of the turned surface's distances to it is at most this share
#: of the diameter
TOLERANCE = 0.08
#: the turns about z that must all be symmetries for a continuous one, degrees
CONTINUOUS_TURNS = (37.0, 90.0, 143.0, 180.0)
#: points sampled on the surface (each of two samples)
POINTS = 20_000
QUANTILE = 0.99


@dataclass(frozen=True)
class ShapeSymmetry:
    """The symmetry found ("none", "180" or "full", about z) and, per turn tried (degrees), the `QUANTILE`
    of the turned surface's distances to the surface, as a share of the diameter."""

    symmetry: str
    misfit: dict[float, float]


def _turn_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def shape_symmetry(mesh: trimesh.Trimesh, diameter_mm: float, seed: int = 0) -> ShapeSymmetry:
    """The symmetry of `mesh`'s shape about its z axis (see the module's docstring)."""
    if diameter_mm <= 0 or len(mesh.faces) == 0:
        return ShapeSymmetry("none", {})
    a = np.asarray(trimesh.sample.sample_surface(mesh, POINTS, seed=seed)[0], float)
    b = np.asarray(trimesh.sample.sample_surface(mesh, POINTS, seed=seed + 1)[0], float)
    surface = cKDTree(a)

    def misfit(deg: float) -> float:
        d = surface.query(b @ _turn_z(deg).T)[0]
        return float(np.quantile(d, QUANTILE) / diameter_mm)

    misfits = {deg: misfit(deg) for deg in sorted({180.0, *CONTINUOUS_TURNS})}
    if all(misfits[deg] <= TOLERANCE for deg in CONTINUOUS_TURNS):
        return ShapeSymmetry("full", misfits)
    return ShapeSymmetry("180" if misfits[180.0] <= TOLERANCE else "none", misfits)


def textured(mesh: trimesh.Trimesh, spread: float = 8.0) -> bool:
    """Whether a mesh carries colours that tell its sides apart: a texture, or vertex or face colours whose
    spread (standard deviation, 0-255, over the channels) is above `spread`. One colour over the whole
    surface (a CAD export's grey) is no more than a shape."""
    visual = mesh.visual
    if isinstance(visual, trimesh.visual.TextureVisuals):
        material = getattr(visual, "material", None)
        image = getattr(material, "image", None) or getattr(material, "baseColorTexture", None)
        return image is not None and visual.uv is not None
    if not isinstance(visual, trimesh.visual.ColorVisuals) or visual.kind is None:
        return False
    colours = visual.vertex_colors if visual.kind == "vertex" else visual.face_colors
    return bool(np.asarray(colours, float)[:, :3].std(axis=0).max() > spread)


#: the symmetry asked for when the registration should decide (`resolve`)
AUTO = "auto"


@dataclass(frozen=True)
class Resolved:
    """The symmetry an object is registered with, where it came from ("given"; "shape": found from a
    shape-only mesh; "colours": a textured mesh, "none" whatever its shape) and whether the mesh has colours."""

    symmetry: str
    source: str
    textured: bool
    found: ShapeSymmetry | None = None


def resolve(mesh: trimesh.Trimesh, asked: str, diameter_mm: float) -> Resolved:
    """The symmetry to register `mesh` with: `asked` unless it is `AUTO`; then "none" for a textured mesh
    (its colours tell the turns apart) and the shape's symmetry (`shape_symmetry`) for a shape-only one."""
    coloured = textured(mesh)
    if asked != AUTO:
        return Resolved(asked, "given", coloured)
    if coloured:
        return Resolved("none", "colours", True)
    found = shape_symmetry(mesh, diameter_mm)
    return Resolved(found.symmetry, "shape", False, found)
