"""The paper's viewpoint sets: vertices of a subdivided icosahedron (one vertex at the +z pole), upper half.

Level 3 (642 vertices) keeps 301 with z > 0: the template viewpoints. Level 4 (2562) keeps 1241: the
training viewpoints. In-plane steps multiply either set without new renders (see `render.rotate_inplane`).

The upper half holds every view of an object standing on the plane its mesh's z axis is the normal of, as
LineMOD's scanned objects stand. A mesh whose frame says nothing of how it lies (a CAD file; YCB-Video's
boxes lying on any face) is seen from below its xy plane as often: `viewpoints(level, whole=True)` adds the
lower half (level 3: 642 viewpoints), upper first.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cache

import numpy as np

from index.geometry.pose import View, wrap_degrees


@cache
def icosphere(level: int) -> np.ndarray:
    """Unit vertices of an icosahedron with a vertex at +z, subdivided `level` times. Shape: (V, 3)."""
    ring = np.arctan(0.5)  # elevation of the two rings of five
    verts = [(0.0, 0.0, 1.0)]
    for i in range(5):
        a = np.radians(72 * i)
        verts.append((np.cos(ring) * np.cos(a), np.cos(ring) * np.sin(a), np.sin(ring)))
    for i in range(5):
        a = np.radians(72 * i + 36)
        verts.append((np.cos(ring) * np.cos(a), np.cos(ring) * np.sin(a), -np.sin(ring)))
    verts.append((0.0, 0.0, -1.0))
    faces = []
    for i in range(5):
        u0, u1 = 1 + i, 1 + (i + 1) % 5
        l0, l1 = 6 + i, 6 + (i + 1) % 5
        faces += [(0, u0, u1), (u0, l0, u1), (u1, l0, l1), (11, l1, l0)]
    v = np.array(verts)
    f = np.array(faces)
    for _ in range(level):
        v, f = _subdivide(v, f)
    return v


def _subdivide(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Splits every triangle into four, new vertices pushed onto the unit sphere."""
    verts = list(map(tuple, v))
    midpoint: dict[tuple[int, int], int] = {}

    def mid(a: int, b: int) -> int:
        key = (min(a, b), max(a, b))
        if key not in midpoint:
            m = (v[a] + v[b]) / 2
            verts.append(tuple(m / np.linalg.norm(m)))
            midpoint[key] = len(verts) - 1
        return midpoint[key]

    faces = []
    for a, b, c in f:
        ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
        faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
    return np.array(verts), np.array(faces)


def hemisphere(level: int = 3) -> np.ndarray:
    """(azimuth, elevation) in degrees of the upper-half vertices (z > 0), pole first. Shape: (N, 2)."""
    return viewpoints(level)


def viewpoints(level: int = 3, whole: bool = False) -> np.ndarray:
    """(azimuth, elevation) in degrees of the upper-half vertices (z > 0), pole first, then with `whole` the
    rest (z <= 0: the equator's and the lower half's), in the icosphere's order. Shape: (N, 2)."""
    v = icosphere(level)
    upper = v[:, 2] > 1e-9
    v = np.concatenate([v[upper], v[~upper]]) if whole else v[upper]
    az = np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 360.0
    el = np.degrees(np.arcsin(np.clip(v[:, 2], -1, 1)))
    az[np.abs(el) > 90 - 1e-6] = 0.0  # a pole's azimuth is a convention: 0
    return np.stack([az, el], axis=1)


def inplane_steps(step_deg: float = 0.0, max_deg: float = 45.0) -> np.ndarray:
    """In-plane angles -max..max in `step_deg` steps (0 always included); step 0 gives just [0].
    `max_deg` >= 180 is the whole turn: every multiple of the step below 360, wrapped to (-180, 180]."""
    if step_deg <= 0:
        return np.zeros(1)
    if max_deg >= 180.0:
        turn = np.arange(int(np.ceil(360.0 / step_deg - 1e-9))) * float(step_deg)
        return np.sort(wrap_degrees(turn))
    n = int(np.floor(max_deg / step_deg + 1e-9))
    return np.arange(-n, n + 1) * float(step_deg)


def whole_turn(inplane: np.ndarray) -> bool:
    """Whether in-plane angles (degrees) go all the way round, evenly (`inplane_steps` of the whole turn)."""
    a = np.sort(np.asarray(inplane, float) % 360.0)
    if len(a) < 2:
        return False
    gaps = np.diff(np.r_[a, a[0] + 360.0])
    return bool(gaps.max() - gaps.min() < 1e-6)


def sphere_views(
    level: int = 3, inplane: np.ndarray | None = None, distance: float = 400.0, whole: bool = False
) -> list[View]:
    """All (viewpoint x in-plane) views, viewpoint-major: the in-plane variants of a viewpoint are adjacent.
    The upper half's viewpoints; with `whole`, every side's (`viewpoints`)."""
    steps = np.zeros(1) if inplane is None else np.asarray(inplane, dtype=float)
    return [
        View(float(az), float(el), float(ip), distance) for az, el in viewpoints(level, whole) for ip in steps
    ]


#: an object record's `extra`: the viewpoints its templates were made from (`VIEWPOINTS`)
VIEWPOINTS_KEY = "viewpoints"
#: the viewpoints an object's templates are made from: "upper", the half-sphere above its mesh's xy plane
#: (an object standing as its mesh's z axis points up, as LineMOD's scans stand: the paper's), or "sphere",
#: every side (an object that may lie on any face, as a CAD file's frame says nothing of how it lies)
VIEWPOINTS = ("upper", "sphere")


def whole_sphere(viewpoints: str | None, default: bool) -> bool:
    """Whether a registration makes its templates from every side: `viewpoints` one of `VIEWPOINTS`, or
    None: `default` (`index.templates.register.TemplateConfig.whole`, the service's `viewpoints` setting)."""
    if viewpoints is None:
        return default
    if viewpoints not in VIEWPOINTS:
        raise ValueError(f"unknown viewpoints {viewpoints!r}; use one of {', '.join(VIEWPOINTS)}")
    return viewpoints == "sphere"


def recorded_whole(extra: Mapping[str, object]) -> bool:
    """Whether a stored object's templates were made from every side (a record before this: the upper half)."""
    return extra.get(VIEWPOINTS_KEY) == "sphere"
