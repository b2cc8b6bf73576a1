"""Object symmetries: the turns of an object that leave it looking the same (the pose errors that forgive
them are `index.pose_error`'s).

A symmetry is one of:
- "none";
- "180": a half-turn about the object's z axis (LineMOD's eggbox and glue, BOP `symmetries_discrete`);
- "full": any turn about the object's z axis (bowls, cans; BOP `symmetries_continuous` about z).
BOP's `symmetries_discrete` 4x4 matrices are read into a list of rotations by `from_bop`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

SYMMETRIES = ("none", "180", "full")
Symmetry = str | Sequence[np.ndarray]  # one of SYMMETRIES, or BOP's discrete rotations


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def symmetry_rotations(symmetry: Symmetry) -> list[np.ndarray]:
    """Object-frame rotations S that leave the object looking the same (identity first).

    "full" is sampled every 1°; `index.pose_error` treats it exactly."""
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
