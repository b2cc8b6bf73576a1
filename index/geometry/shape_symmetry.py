"""An object's symmetry found from its shape: what a mesh without colour looks like after a turn.

A shape-only mesh (a CAD file, YCB-Video's meshes) looks the same after any turn that maps its surface onto
itself: a box after a half-turn about each of its axes, a can after any turn about its axis and end over
end. Nothing tells those poses apart in depth, and in colour only the silhouette and shading, so the
templates need only one of them and a pose error must forgive them (`symmetry`). A textured object's
colours break the symmetry of its shape: its symmetry is "none" unless its owner says otherwise.

The test: points sampled on the surface, turned, and the 99th percentile of their distances to the surface
(another sample of it) compared with the object's diameter: a high percentile, so that a small part that
breaks the symmetry (a mug's handle, a nozzle) counts. A turn is a symmetry when that stays within
`TOLERANCE` of the diameter: a scanned box's half-turn comes out at 2-6 % (its faces are not flat), an
object that is not symmetric at 10 % and more (LM-O's five, a mug, a banana). Turns about the z axis
first: "full" when every one of a set of turns (`CONTINUOUS_TURNS`, one of them not a fraction of the turn
that a 2-, 3-, 4-, 5- or 6-fold symmetry repeats on) is, else "180" or "none", unless the shape is round
about its x or y axis (a pen lying along y: "y:full"); then the flip, a half-turn end over end about an
axis across that axis, through the middle of the object's extent along it (`centre`): every `FLIP_STEP`
degrees on a tenth of the points, then to the degree about the best (a box whose sides are not along its
mesh's x and y axes has its flip at some angle; x or y when it fits as well). Measured on LM-O's and
YCB-Video's meshes: docs/experiments.md, "Shape-only meshes" and "A box's half-turns". Deterministic
(seeded sampling), under 1.6 s for YCB-Video's meshes. The tolerance is a share of the whole diameter: a
long thin bar of square section (turned, its corners move little against its length) is taken as round.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from index.geometry.symmetry import Named, canonical, flip_rotation

#: a turn is a symmetry when the `QUANTILE` of the turned surface's distances to it is at most this share
#: of the diameter
TOLERANCE = 0.08
#: the turns about z that must all be symmetries for a continuous one, degrees
CONTINUOUS_TURNS = (37.0, 90.0, 143.0, 180.0)
#: points sampled on the surface (each of two samples)
POINTS = 20_000
QUANTILE = 0.99
#: the flip's axis is first looked for every this many degrees, on every `FLIP_SUBSAMPLE`-th point
FLIP_STEP = 5
FLIP_SUBSAMPLE = 10
#: the mesh's own axis is taken for the flip when its misfit is within this of the best axis's
AXIS_PREFERENCE = 0.005


@dataclass(frozen=True)
class ShapeSymmetry:
    """The symmetry found (a name of `index.geometry.symmetry`), per turn about z tried (degrees) the
    `QUANTILE` of the turned surface's distances to the surface as a share of the diameter, the same of the
    best flip (None: not tried), and the centre its turns are about (mm: on its axis, mid-extent)."""

    symmetry: str
    misfit: dict[float, float]
    flip_misfit: float | None = None
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)


def _turn_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def shape_symmetry(mesh: trimesh.Trimesh, diameter_mm: float, seed: int = 0) -> ShapeSymmetry:
    """The symmetry of `mesh`'s shape (see the module's docstring)."""
    if diameter_mm <= 0 or len(mesh.faces) == 0:
        return ShapeSymmetry("none", {})
    a = np.asarray(trimesh.sample.sample_surface(mesh, POINTS, seed=seed)[0], float)
    b = np.asarray(trimesh.sample.sample_surface(mesh, POINTS, seed=seed + 1)[0], float)
    surface = cKDTree(a)
    middle = np.mean(mesh.bounds, axis=0)

    def misfit_about(axis: str) -> tuple[Callable[..., float], np.ndarray]:
        """The misfit of a turn (given in the frame whose z is `axis`) about the axis's mid-point, and that
        point."""
        P = Named("none", axis=axis).frame
        centre = P[:, 2] * (P[:, 2] @ middle)

        def misfit(R: np.ndarray, every: int = 1) -> float:
            d = surface.query((b[::every] - centre) @ (P @ R @ P.T).T + centre)[0]
            return float(np.quantile(d, QUANTILE) / diameter_mm)

        return misfit, centre

    axis, (misfit, centre) = "z", misfit_about("z")
    misfits = {deg: misfit(_turn_z(deg)) for deg in sorted({180.0, *CONTINUOUS_TURNS})}
    if all(misfits[deg] <= TOLERANCE for deg in CONTINUOUS_TURNS):
        about = "full"
    else:
        about = "180" if misfits[180.0] <= TOLERANCE else "none"
        for other in ("x", "y"):  # round about another of the mesh's axes (a pen lying along y)
            turned, mid = misfit_about(other)
            if all(turned(_turn_z(deg)) <= TOLERANCE for deg in CONTINUOUS_TURNS):
                about, axis, misfit, centre = "full", other, turned, mid
                break
    flip_deg, flip_misfit = _best_flip(about, misfit)
    named = Named(about, flip_deg if flip_misfit <= TOLERANCE else None, axis)
    x, y, z = (float(v) for v in centre)
    return ShapeSymmetry(named.name, misfits, flip_misfit, (x, y, z))


def _best_flip(about_z: str, misfit: Callable[..., float]) -> tuple[float, float]:
    """The flip's axis (degrees from x) that fits best, and its misfit; the mesh's x (or y) axis when it
    fits as well, within `AXIS_PREFERENCE` (a square's diagonals are flips as good as its sides). With "full"
    any axis is as good; with "180" the axes repeat every 90°, else every 180°."""
    if about_z == "full":
        return 0.0, misfit(flip_rotation(0.0))
    span = 90 if about_z == "180" else 180
    coarse = {deg: misfit(flip_rotation(deg), FLIP_SUBSAMPLE) for deg in range(0, span, FLIP_STEP)}
    best = min(coarse, key=coarse.__getitem__)
    half = FLIP_STEP // 2
    fine = {deg % span: misfit(flip_rotation(deg)) for deg in range(best - half, best + half + 1)}
    for axis in (0, 90)[: span // 90]:
        fine.setdefault(axis, misfit(flip_rotation(axis)))
    deg = min(fine, key=fine.__getitem__)
    axis = min((0, 90)[: span // 90], key=fine.__getitem__)
    if fine[axis] <= fine[deg] + AXIS_PREFERENCE:
        deg = axis
    return float(deg), fine[deg]


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
    """The symmetry to register `mesh` with: `asked` (a name of `index.geometry.symmetry`, ValueError if it
    is not one) unless it is `AUTO`; then "none" for a textured mesh
    (its colours tell the turns apart) and the shape's symmetry (`shape_symmetry`) for a shape-only one."""
    if asked != AUTO:
        return Resolved(canonical(asked), "given", textured(mesh))
    coloured = textured(mesh)
    if coloured:
        return Resolved("none", "colours", True)
    found = shape_symmetry(mesh, diameter_mm)
    return Resolved(found.symmetry, "shape", False, found)
