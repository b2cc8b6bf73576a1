"""How far an object's origin lies behind the surface seen at the centre of a template.

One meaning of distance everywhere: the distance from the camera to the object's origin along the ray
through its centre (‖t‖ of a BOP pose); templates are cut with the window at that distance. A depth
sensor sees the surface instead, nearer by up to the object's radius, and by how much depends on the
object and the viewpoint. So each template viewpoint keeps its offset, origin minus surface, the surface
measured on the template's depth by the same rule the service measures a query's (`surface_depth`: the
median of the central quarter of the window); the service adds the answer's offset to the surface it
measured to place the answer's origin (`service.recognition`). In-plane turns do not move the centre, so
one offset per (azimuth, elevation) serves every in-plane variant."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from index.features.patches import surface_depth
from index.geometry.pose import View

#: an object record's `extra` key: [[azimuth, elevation, offset mm], ...], one row per viewpoint
SURFACE_KEY = "surface_offsets"


def template_offsets(depth: np.ndarray, views: Sequence[View], window_mm: float) -> np.ndarray:
    """Origin minus surface (mm) of upright rendered templates. Shape: depth (N, S, S) -> (M, 3) rows of
    azimuth, elevation, offset for the M upright views (0 where no surface shows near the centre)."""
    up = [i for i, v in enumerate(views) if abs(v.inplane) < 1e-3]
    if not up:
        return np.zeros((0, 3))
    nominal = np.array([views[i].distance for i in up], float)
    surface = surface_depth(np.asarray(depth)[up], nominal, window_mm)
    poses = np.array([(views[i].azimuth, views[i].elevation) for i in up], float)
    return np.column_stack([poses, nominal - surface])


def offset_of(extra: Mapping[str, object], azimuth: float, elevation: float) -> float | None:
    """The offset of the stored viewpoint nearest (azimuth, elevation); None for an object registered
    before offsets were kept."""
    rows = extra.get(SURFACE_KEY)
    if not rows:
        return None
    a = np.asarray(rows, float)
    az, el = np.radians(a[:, 0]), np.radians(a[:, 1])
    qa, qe = np.radians(azimuth), np.radians(elevation)
    cos = np.sin(el) * np.sin(qe) + np.cos(el) * np.cos(qe) * np.cos(az - qa)  # angle between directions
    return float(a[int(np.argmax(cos)), 2])
