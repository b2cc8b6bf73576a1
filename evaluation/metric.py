"""The paper's metric: for k = 1…22, the fraction of test patches whose best pose among the k nearest
templates is within 5°, 20°, 40° of the truth; a template of the wrong object counts as 180°, so the
180° column is the recognition rate (the right object is among the k nearest).

Pose errors are those of `index.symmetry`, symmetry-aware, vectorised over templates:
- `--protocol paper`: the angle between viewing directions on the half-sphere (`view_error`);
- `--protocol full`: the 3-D rotation angle (`rotation_error`), in-plane included.
Views are those of patches seen along their own optical axis (index/pose.py)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from index.pose import View, camera_centre, view_to_pose
from index.symmetry import symmetry_rotations

THRESHOLDS = (5, 20, 40, 180)  # degrees; 180 = the right object, whatever the pose
K_MAX = 22
WRONG_OBJECT = 180.0
PROTOCOLS = ("paper", "full")


@dataclass(frozen=True)
class Poses:
    """Views as arrays. elevation (M,) degrees; centres (M, 3) unit camera centres; R (M, 3, 3) R_m2c."""

    elevation: np.ndarray
    centres: np.ndarray
    R: np.ndarray

    @classmethod
    def of(cls, views: Sequence[View]) -> Poses:
        return cls(
            elevation=np.array([v.elevation for v in views], float),
            centres=np.array([camera_centre(v.azimuth, v.elevation) for v in views]).reshape(-1, 3),
            R=np.array([view_to_pose(View(v.azimuth, v.elevation, v.inplane))[0] for v in views]).reshape(
                -1, 3, 3
            ),
        )

    def take(self, idx: np.ndarray) -> Poses:
        return Poses(self.elevation[idx], self.centres[idx], self.R[idx])


def pose_errors(est: Poses, gt: Poses, symmetry, protocol: str) -> np.ndarray:
    """Degrees between each estimated pose and the one true pose `gt` (a Poses of length 1). Shape: (M,)."""
    if protocol == "paper":
        if symmetry == "full":  # only elevation is observable
            return np.abs(est.elevation - gt.elevation[0])
        # The pose R_gt @ S puts the camera centre at S^T c_gt in the object frame.
        cos = np.max([est.centres @ (S.T @ gt.centres[0]) for S in symmetry_rotations(symmetry)], axis=0)
    elif protocol == "full":
        if symmetry == "full":  # only the object's z axis is observable
            cos = est.R[:, :, 2] @ gt.R[0][:, 2]
        else:
            # trace(R_est^T R_gt S) = sum of the element-wise product.
            traces = [np.einsum("mij,ij->m", est.R, gt.R[0] @ S) for S in symmetry_rotations(symmetry)]
            cos = (np.max(traces, axis=0) - 1.0) / 2.0
    else:
        raise ValueError(f"unknown protocol {protocol!r}; use one of {PROTOCOLS}")
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def neighbour_errors(
    neighbours: np.ndarray,
    template_obj: np.ndarray,
    template_poses: Poses,
    sample_obj: np.ndarray,
    sample_poses: Poses,
    symmetries: dict[int, object],
    protocol: str,
) -> np.ndarray:
    """Pose error of every retrieved template. neighbours: (N, K) template indices, -1 = nothing
    retrieved (counts as a wrong object). Returns (N, K) degrees, wrong object = 180."""
    errors = np.full(neighbours.shape, WRONG_OBJECT)
    for i, row in enumerate(neighbours):
        hit = (row >= 0) & (template_obj[np.maximum(row, 0)] == sample_obj[i])
        if hit.any():
            obj = int(sample_obj[i])
            errors[i, hit] = pose_errors(
                template_poses.take(row[hit]), sample_poses.take([i]), symmetries[obj], protocol
            )
    return errors


def same_object(neighbours: np.ndarray, template_obj: np.ndarray, sample_obj: np.ndarray) -> np.ndarray:
    """(N, K) bool: the retrieved template is of the sample's object."""
    return (neighbours >= 0) & (template_obj[np.maximum(neighbours, 0)] == sample_obj[:, None])


def accuracy(
    errors: np.ndarray, same: np.ndarray, ks: Sequence[int] = range(1, K_MAX + 1)
) -> dict[str, dict[str, float]]:
    """{"k1": {"5": f, "20": f, "40": f, "180": f}, ...} from errors and same-object flags (N, K_MAX).

    A threshold t < 180 counts a patch when the best error among its k nearest is ≤ t; the 180 column
    counts it when the right object is among its k nearest (wrong objects count as 180°)."""
    out: dict[str, dict[str, float]] = {}
    n = len(errors)
    for k in ks:
        if n == 0:
            out[f"k{k}"] = {str(t): 0.0 for t in THRESHOLDS}
            continue
        best = errors[:, :k].min(axis=1)
        row = {str(t): float(np.mean(best <= t)) for t in THRESHOLDS if t < 180}
        row["180"] = float(np.mean(same[:, :k].any(axis=1)))
        out[f"k{k}"] = row
    return out


def accuracy_curve(errors: np.ndarray, k: int, thresholds: np.ndarray) -> np.ndarray:
    """Fraction of patches whose best error among the k nearest is ≤ each threshold. Shape: (len(t),)."""
    best = errors[:, :k].min(axis=1)
    return np.array([np.mean(best <= t) for t in thresholds]) if len(best) else np.zeros(len(thresholds))
