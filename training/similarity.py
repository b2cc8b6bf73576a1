"""Symmetry-aware pose similarity, in-plane rotation included: which template is "the same pose" as a
training sample, and which of two templates is closer to it (the paper's triplet condition).

A pose here is the rotation R_m2c of a view with the object on the optical axis (`index.geometry.pose.view_to_pose`),
so azimuth, elevation and in-plane all count. Distances are `index.geometry.pose_error.rotation_error`, vectorised:
the smallest angle between R_a and any R_b @ S with S a symmetry of the object; for "full" (any turn
about z) only where the object's z axis points is observable (`index.geometry.pose_error.rotation_errors`)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from index.geometry.pose import View, view_to_pose
from index.geometry.pose_error import rotation_errors

Symmetry = str | Sequence[np.ndarray]


def rotations(views: Sequence[View]) -> np.ndarray:
    """R_m2c of each view, on the optical axis. Shape: (N, 3, 3)."""
    return np.stack([view_to_pose(v)[0] for v in views])


def pose_distances(R_a: np.ndarray, R_b: np.ndarray, symmetry: Symmetry = "none") -> np.ndarray:
    """Symmetry-aware angles (degrees) between every R_a and every R_b. Shape: (A, 3, 3), (B, 3, 3) -> (A, B).

    Equals `index.geometry.pose_error.rotation_error(R_a[i], R_b[j], symmetry)` for every pair."""
    return rotation_errors(R_a, R_b, symmetry)


def closer(R: np.ndarray, R_j: np.ndarray, R_k: np.ndarray, symmetry: Symmetry = "none") -> bool:
    """The paper's condition for a same-object triplet: pose j is closer to pose i than pose k is."""
    d = pose_distances(R[None], np.stack([R_j, R_k]), symmetry)[0]
    return bool(d[0] < d[1])
