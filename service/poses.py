"""Each answer's pose in the query's camera, as BOP writes it (`cam_R_m2c`, `cam_t_m2c`): the answer's
viewpoint and in-plane angle seen along the ray through the object's centre, at the distance the query was
cut at (`index.geometry.pose.view_to_pose`; the conventions are stated there)."""

from __future__ import annotations

import numpy as np

from index.geometry.pose import View, view_to_pose
from index.store import Match


def match_pose(m: Match, ray: np.ndarray, distance_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """(R_m2c (3, 3), t_m2c (3,) mm) of an answer; `ray` (3,) in the query's camera."""
    return view_to_pose(View(m.azimuth, m.elevation, m.inplane, distance_mm), ray)
