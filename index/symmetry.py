"""Object symmetries and symmetry-aware pose errors (the names and units of bop_toolkit's pose_error).

A symmetry is one of:
- "none";
- "180": a half-turn about the object's z axis (LineMOD's eggbox and glue, BOP `symmetries_discrete`);
- "full": any turn about the object's z axis (bowls, cans; BOP `symmetries_continuous` about z).
BOP's `symmetries_discrete` 4x4 matrices are read into a list of rotations by `from_bop`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from index.pose import camera_centre, rotation_angle

SYMMETRIES = ("none", "180", "full")


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def symmetry_rotations(symmetry: str | Sequence[np.ndarray]) -> list[np.ndarray]:
    """Object-frame rotations S that leave the object looking the same (identity first).

    "full" is sampled every 1°; errors under it are computed exactly by `rotation_error`."""
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


def rotation_error(
    R_est: np.ndarray, R_gt: np.ndarray, symmetry: str | Sequence[np.ndarray] = "none"
) -> float:
    """Smallest angle (degrees) between R_est and any pose R_gt @ S that looks the same."""
    if symmetry == "full":
        # Only the object's z axis is observable: the angle between where the two poses put it.
        cos = float(np.clip((R_est @ [0, 0, 1.0]) @ (R_gt @ [0, 0, 1.0]), -1.0, 1.0))
        return float(np.degrees(np.arccos(cos)))
    return min(rotation_angle(R_est, R_gt @ S) for S in symmetry_rotations(symmetry))


def view_error(
    az_est: float, el_est: float, az_gt: float, el_gt: float, symmetry: str | Sequence[np.ndarray] = "none"
) -> float:
    """Angle (degrees) between viewing directions on the sphere, the smallest over the symmetries
    (the paper's pose error). Under "full" only elevation is observable."""
    c_est = camera_centre(az_est, el_est)
    c_gt = camera_centre(az_gt, el_gt)
    if symmetry == "full":
        return abs(el_est - el_gt)
    # The pose R_gt @ S puts the camera centre at S^T c_gt in the object frame.
    best = max(float(c_est @ (S.T @ c_gt)) for S in symmetry_rotations(symmetry))
    return float(np.degrees(np.arccos(np.clip(best, -1.0, 1.0))))
