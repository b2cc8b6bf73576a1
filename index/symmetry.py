"""Object symmetries and the symmetry-aware pose errors (the names and units of bop_toolkit's pose_error),
the one definition that the evaluation, the service's tests and training use:
- `rotation_errors`: the 3-D rotation angle, in-plane included;
- `view_errors`: the angle between viewing directions (the paper's error; in-plane does not count);
- `within`: an error counts as within t degrees when it is strictly below t, as BOP counts.

A symmetry is one of:
- "none";
- "180": a half-turn about the object's z axis (LineMOD's eggbox and glue, BOP `symmetries_discrete`);
- "full": any turn about the object's z axis (bowls, cans; BOP `symmetries_continuous` about z).
BOP's `symmetries_discrete` 4x4 matrices are read into a list of rotations by `from_bop`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from index.pose import lookat_rotation

SYMMETRIES = ("none", "180", "full")
Symmetry = str | Sequence[np.ndarray]  # one of SYMMETRIES, or BOP's discrete rotations


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def symmetry_rotations(symmetry: Symmetry) -> list[np.ndarray]:
    """Object-frame rotations S that leave the object looking the same (identity first).

    "full" is sampled every 1°; the errors below treat it exactly."""
    if not isinstance(symmetry, str):
        return [np.eye(3)] + [np.asarray(S, float)[:3, :3] for S in symmetry]
    if symmetry == "none":
        return [np.eye(3)]
    if symmetry == "180":
        return [np.eye(3), _rot_z(180.0)]
    if symmetry == "full":
        return [_rot_z(a) for a in range(360)]
    raise ValueError(f"unknown symmetry {symmetry!r}; use one of {SYMMETRIES}")


def from_bop(info: dict) -> str | list[np.ndarray]:
    """The symmetry of a `models_info.json` entry."""
    if info.get("symmetries_continuous"):
        return "full"
    discrete = info.get("symmetries_discrete") or []
    if not discrete:
        return "none"
    mats = [np.asarray(m, float).reshape(4, 4) for m in discrete]
    if len(mats) == 1 and np.allclose(mats[0][:3, :3], _rot_z(180.0), atol=0.05):
        return "180"
    return mats


def _stack(R: np.ndarray) -> np.ndarray:
    return np.asarray(R, dtype=float).reshape(-1, 3, 3)


def _degrees(cos: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def rotation_errors(R_est: np.ndarray, R_gt: np.ndarray, symmetry: Symmetry = "none") -> np.ndarray:
    """3-D rotation error, in-plane included: the smallest angle (degrees) between each R_est and any
    pose R_gt @ S that looks the same (S a symmetry of the object). Under "full" only where the two
    poses put the object's z axis is observable. Shape: (N, 3, 3), (M, 3, 3) -> (N, M)."""
    R_est, R_gt = _stack(R_est), _stack(R_gt)
    if isinstance(symmetry, str) and symmetry == "full":
        return _degrees(R_est[:, :, 2] @ R_gt[:, :, 2].T)
    # trace(R_est^T R_gt S) is the sum of the element-wise product of R_est and R_gt S.
    trace = np.max([np.einsum("nij,mij->nm", R_est, R_gt @ S) for S in symmetry_rotations(symmetry)], axis=0)
    return _degrees((trace - 1.0) / 2.0)


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
    if isinstance(symmetry, str) and symmetry == "full":
        el_est, el_gt = np.arcsin(np.clip(c_est[:, 2], -1, 1)), np.arcsin(np.clip(c_gt[:, 2], -1, 1))
        return np.degrees(np.abs(el_est[:, None] - el_gt[None, :]))
    # The pose R_gt @ S puts the camera at S^T c_gt in the object frame.
    return _degrees(np.max([c_est @ (c_gt @ S).T for S in symmetry_rotations(symmetry)], axis=0))


def within(errors: np.ndarray, threshold: float) -> np.ndarray:
    """Which errors count as within `threshold` degrees: strictly below it, as BOP counts."""
    return np.asarray(errors) < threshold


def rotation_error(R_est: np.ndarray, R_gt: np.ndarray, symmetry: Symmetry = "none") -> float:
    """`rotation_errors` of one pair of poses, degrees."""
    return float(rotation_errors(R_est, R_gt, symmetry)[0, 0])


def view_error(
    az_est: float, el_est: float, az_gt: float, el_gt: float, symmetry: Symmetry = "none"
) -> float:
    """`view_errors` of two viewpoints given as azimuth and elevation (degrees), degrees."""
    return float(view_errors(lookat_rotation(az_est, el_est), lookat_rotation(az_gt, el_gt), symmetry)[0, 0])
