"""Symmetry-aware pose similarity, in-plane rotation included: which template is "the same pose" as a
training sample, and which of two templates is closer to it (the paper's triplet condition).

A pose here is the rotation R_m2c of a view with the object on the optical axis (`index.geometry.pose.view_to_pose`),
so azimuth, elevation and in-plane all count. Distances are `index.geometry.pose_error.rotation_error`, vectorised:
the smallest angle between R_a and any R_b @ S with S a symmetry of the object; for "full" (any turn
about z) only where the object's z axis points is observable."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from index.geometry.pose import View, view_to_pose
from index.geometry.symmetry import symmetry_rotations

Symmetry = str | Sequence[np.ndarray]


def rotations(views: Sequence[View]) -> np.ndarray:
    """R_m2c of each view, on the optical axis. Shape: (N, 3, 3)."""
    return np.stack([view_to_pose(v)[0] for v in views])


def pose_distances(R_a: np.ndarray, R_b: np.ndarray, symmetry: Symmetry = "none") -> np.ndarray:
    """Symmetry-aware angles (degrees) between every R_a and every R_b. Shape: (A, 3, 3), (B, 3, 3) -> (A, B).

    Equals `index.geometry.pose_error.rotation_error(R_a[i], R_b[j], symmetry)` for every pair."""
    R_a, R_b = np.asarray(R_a, float).reshape(-1, 3, 3), np.asarray(R_b, float).reshape(-1, 3, 3)
    if isinstance(symmetry, str) and symmetry == "full":
        cos = np.einsum("ai,bi->ab", R_a[:, :, 2], R_b[:, :, 2])  # where each pose puts the object's z
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    best = np.full((len(R_a), len(R_b)), -np.inf)
    for S in symmetry_rotations(symmetry):
        RbS = R_b @ S
        # trace(R_a^T R_b S) for all pairs
        tr = np.einsum("aij,bij->ab", R_a, RbS)
        best = np.maximum(best, tr)
    cos = (best - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def closer(R: np.ndarray, R_j: np.ndarray, R_k: np.ndarray, symmetry: Symmetry = "none") -> bool:
    """The paper's condition for a same-object triplet: pose j is closer to pose i than pose k is."""
    d = pose_distances(R[None], np.stack([R_j, R_k]), symmetry)[0]
    return bool(d[0] < d[1])
