"""Pose errors, the one definition the evaluation, the service's tests and training use (the names and
units of bop_toolkit's `pose_error.py`, so our numbers compare with BOP's).

Conventions: `R_est`, `R_gt` are rotations R_m2c (object to camera, OpenCV axes: `index.pose`), one (3, 3)
or a stack (N, 3, 3); `t_est`, `t_gt` translations in mm; errors are degrees (angles) or mm (distances).
Cosines are clipped to [-1, 1] before `arccos`. Every error respects the object's symmetry
(`index.symmetry`): the smallest error over the poses that look the same.

- `rotation_errors` / `rotation_error`: the 3-D rotation angle, in-plane included;
- `view_errors` / `view_error`: the angle between viewing directions (the paper's error; in-plane does
  not count);
- `within`: an error counts as within t when it is strictly below t, as BOP counts.

BOP's model-based errors (MSSD, MSPD, VSD, ADD(-S)), which take `t_est`, `t_gt` and the model's points,
belong here too."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from index.pose import lookat_rotation
from index.symmetry import Symmetry, symmetry_rotations


def _stack(R: np.ndarray) -> np.ndarray:
    return np.asarray(R, dtype=float).reshape(-1, 3, 3)


def _degrees(cos: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _is_full(symmetry: Symmetry) -> bool:
    return isinstance(symmetry, str) and symmetry == "full"


def rotation_errors(R_est: np.ndarray, R_gt: np.ndarray, symmetry: Symmetry = "none") -> np.ndarray:
    """3-D rotation error, in-plane included: the smallest angle (degrees) between each R_est and any
    pose R_gt @ S that looks the same (S a symmetry of the object). Under "full" only where the two
    poses put the object's z axis is observable. Shape: (N, 3, 3), (M, 3, 3) -> (N, M)."""
    R_est, R_gt = _stack(R_est), _stack(R_gt)
    if _is_full(symmetry):
        return _degrees(R_est[:, :, 2] @ R_gt[:, :, 2].T)
    # trace(R_est^T R_gt S) is the sum of the element-wise product of R_est and R_gt S.
    trace = np.max([np.einsum("nij,mij->nm", R_est, R_gt @ S) for S in symmetry_rotations(symmetry)], axis=0)
    return _degrees((trace - 1.0) / 2.0)


def rotation_error(R_est: np.ndarray, R_gt: np.ndarray, symmetry: Symmetry = "none") -> float:
    """`rotation_errors` of one pair of poses (3, 3), degrees."""
    return float(rotation_errors(R_est, R_gt, symmetry)[0, 0])


def view_errors(
    R_est: np.ndarray,
    R_gt: np.ndarray,
    symmetry: Symmetry = "none",
    ray: np.ndarray | Sequence[float] = (0.0, 0.0, 1.0),
) -> np.ndarray:
    """Viewing-direction error (the paper's pose error): the angle (degrees) between where the two poses
    put the camera as seen from the object, -R^T ray for an object on `ray` (camera frame; both poses on
    it), the smallest over the symmetries; in-plane does not count. Under "full" only elevation is
    observable. Shape: (N, 3, 3), (M, 3, 3) -> (N, M)."""
    R_est, R_gt = _stack(R_est), _stack(R_gt)
    r = np.asarray(ray, dtype=float) / np.linalg.norm(ray)
    c_est, c_gt = -np.einsum("k,nkj->nj", r, R_est), -np.einsum("k,nkj->nj", r, R_gt)
    if _is_full(symmetry):
        el_est, el_gt = np.arcsin(np.clip(c_est[:, 2], -1, 1)), np.arcsin(np.clip(c_gt[:, 2], -1, 1))
        return np.degrees(np.abs(el_est[:, None] - el_gt[None, :]))
    # The pose R_gt @ S puts the camera at S^T c_gt in the object frame.
    return _degrees(np.max([c_est @ (c_gt @ S).T for S in symmetry_rotations(symmetry)], axis=0))


def view_error(
    az_est: float, el_est: float, az_gt: float, el_gt: float, symmetry: Symmetry = "none"
) -> float:
    """`view_errors` of two viewpoints given as azimuth and elevation (degrees, `index.pose`), degrees."""
    return float(view_errors(lookat_rotation(az_est, el_est), lookat_rotation(az_gt, el_gt), symmetry)[0, 0])


def within(errors: np.ndarray, threshold: float) -> np.ndarray:
    """Which errors count as within `threshold` (same unit): strictly below it, as BOP counts."""
    return np.asarray(errors) < threshold
