"""The paper's metric: for k = 1…22, the fraction of test patches whose best pose among the k nearest
answers is within 5°, 20°, 40° of the truth (strictly below, as BOP: `index.geometry.pose_error.within`); a wrong
object counts as 180°, so the 180° column is the recognition rate (the right object is among the k).

Pose errors are `index.geometry.pose_error`'s, symmetry-aware, vectorised over answers:
- `--protocol paper`: the angle between viewing directions (`view_errors`);
- `--protocol full` and `service`: the 3-D rotation angle (`rotation_errors`), in-plane included (the
  service protocol reports the viewing-direction error beside it).
Views are those of patches seen along their own optical axis (index/geometry/pose.py)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from index.geometry.pose import View, view_to_pose
from index.geometry.pose_error import rotation_errors, view_errors, within
from index.geometry.symmetry import Symmetry

THRESHOLDS = (5, 20, 40, 180)  # degrees; 180 = the right object, whatever the pose
K_MAX = 22
WRONG_OBJECT = 180.0
PROTOCOLS = ("service", "paper", "full")


@dataclass(frozen=True)
class Poses:
    """Views as rotations: R (M, 3, 3), R_m2c with the object on the optical axis."""

    R: np.ndarray

    @classmethod
    def of(cls, views: Sequence[View]) -> Poses:
        R = [view_to_pose(View(v.azimuth, v.elevation, v.inplane))[0] for v in views]
        return cls(np.array(R).reshape(-1, 3, 3))

    def take(self, idx: np.ndarray | Sequence[int]) -> Poses:
        return Poses(self.R[idx])


def pose_errors(est: Poses, gt: Poses, symmetry: Symmetry, protocol: str) -> np.ndarray:
    """Degrees between each estimated pose and the one true pose `gt` (a Poses of length 1). Shape: (M,)."""
    if protocol == "paper":
        return view_errors(est.R, gt.R[:1], symmetry)[:, 0]
    if protocol in ("full", "service"):
        return rotation_errors(est.R, gt.R[:1], symmetry)[:, 0]
    raise ValueError(f"unknown protocol {protocol!r}; use one of {PROTOCOLS}")


def neighbour_errors(
    neighbours: np.ndarray,
    template_obj: np.ndarray,
    template_poses: Poses,
    sample_obj: np.ndarray,
    sample_poses: Poses,
    symmetries: Mapping[int, Symmetry],
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

    A threshold t < 180 counts a patch when the best error among its k nearest is within t (strictly
    below it); the 180 column counts it when the right object is among its k nearest."""
    out: dict[str, dict[str, float]] = {}
    n = len(errors)
    for k in ks:
        if n == 0:
            out[f"k{k}"] = {str(t): 0.0 for t in THRESHOLDS}
            continue
        best = errors[:, :k].min(axis=1)
        row = {str(t): float(np.mean(within(best, t))) for t in THRESHOLDS if t < 180}
        row["180"] = float(np.mean(same[:, :k].any(axis=1)))
        out[f"k{k}"] = row
    return out
