"""Where each answer puts the object's origin along the ray: the distance its `t` is at.

`distance_mm`, sent or not, means one thing: from the camera to the object's origin along the ray through
the centre (‖t‖). Sent, it is the answer's distance. Measured from depth, it is the surface at the centre
(the median of the central quarter of the patch, as the templates measure theirs), and each answer adds its
own template's offset (origin minus surface for that object from that viewpoint, `index.surface`): the
surface of a mug seen from the side lies its radius in front of its origin, seen from above its half height."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from index.patches import surface_depth
from index.store import Match, Snapshot
from index.surface import offset_of


def origin_distances(
    snap: Snapshot,
    matches: Sequence[Match],
    cut_mm: float,
    depth_patch: np.ndarray | None,
    window_mm: float,
    measured: bool,
) -> list[float]:
    """Each match's distance to the object's origin, mm. `cut_mm`: the distance the query was cut at
    (given, or the surface measured at the centre); `measured`: it came from depth, so the surface on
    `depth_patch` (S, S) plus each match's offset is the origin (`cut_mm` for an object without offsets)."""
    if not measured or depth_patch is None:
        return [cut_mm] * len(matches)
    surface = float(surface_depth(depth_patch, cut_mm, window_mm))
    out = []
    for m in matches:
        rec = snap.objects.get(m.object_id)
        offset = None if rec is None else offset_of(rec.extra, m.azimuth, m.elevation)
        out.append(cut_mm if offset is None else surface + offset)
    return out
