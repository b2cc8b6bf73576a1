"""Object symmetries: the turns of an object that leave it looking the same (the pose errors that forgive
them are `index.geometry.pose_error`'s).

A symmetry is one of:
- "none";
- "180": a half-turn about the object's z axis (LineMOD's eggbox and glue, BOP `symmetries_discrete`);
- "full": any turn about the object's z axis (bowls, cans; BOP `symmetries_continuous` about z).
BOP's `symmetries_discrete` 4x4 matrices are read into a list of rotations by `from_bop`.
`symmetry_transformations` gives the (R, t) transformations BOP's MSSD and MSPD minimise over.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from index.geometry.pose import rotation_of

SYMMETRIES = ("none", "180", "full")
Symmetry = str | Sequence[np.ndarray]  # one of SYMMETRIES, or BOP's discrete rotations


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def symmetry_rotations(symmetry: Symmetry) -> list[np.ndarray]:
    """Object-frame rotations S that leave the object looking the same (identity first).

    "full" is sampled every 1°; `index.geometry.pose_error` treats it exactly."""
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


def bop_form(symmetry: str) -> dict:
    """One of `SYMMETRIES` as `models_info.json` states it (`from_bop`'s inverse): the keys to add."""
    if symmetry == "full":
        return {"symmetries_continuous": [{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 0.0]}]}
    if symmetry == "180":
        return {"symmetries_discrete": [_half_turn()]}
    if symmetry == "none":
        return {}
    raise ValueError(f"unknown symmetry {symmetry!r}; use one of {SYMMETRIES}")


def _half_turn() -> list[float]:
    m = np.eye(4)
    m[:3, :3] = _rot_z(180.0)
    return m.ravel().tolist()


#: BOP's rule for discretising a continuous symmetry: no model point may move more than this fraction of
#: the object's diameter between two neighbouring samples (bop_toolkit's default `max_sym_disc_step`).
MAX_SYM_DISC_STEP = 0.01


def continuous_steps(max_step: float = MAX_SYM_DISC_STEP) -> int:
    """How many equal turns sample a full turn about an axis so that no point moves more than `max_step`
    diameters between neighbours: a point at most d/2 from the axis moves d·sin(π/n) ≤ d·π/n per step."""
    return int(np.ceil(np.pi / max_step))


def symmetry_transformations(
    symmetry: Symmetry, max_step: float = MAX_SYM_DISC_STEP
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The object-frame transformations x -> R x + t (t in mm) that leave the object looking the same,
    identity first, as BOP's model-based errors (MSSD, MSPD) minimise over them.

    "full" (a continuous symmetry about z through the origin) is sampled by BOP's max-distance rule
    (`continuous_steps`); BOP's discrete 4x4 matrices keep their translation offsets."""
    if isinstance(symmetry, str) and symmetry == "full":
        n = continuous_steps(max_step)
        return [(_rot_z(360.0 * i / n), np.zeros(3)) for i in range(n)]
    if not isinstance(symmetry, str):
        mats = [np.asarray(m, float) for m in symmetry]
        mats = [m.reshape(4, 4) if m.size == 16 else m.reshape(3, 3) for m in mats]
        return [(np.eye(3), np.zeros(3))] + [(m[:3, :3], _offset(m)) for m in mats]
    return [(S, np.zeros(3)) for S in symmetry_rotations(symmetry)]


def _offset(m: np.ndarray) -> np.ndarray:
    """The translation of a 4x4 symmetry (BOP's offset, mm); a bare 3x3 rotation has none."""
    return m[:3, 3].copy() if m.shape == (4, 4) else np.zeros(3)


def _axis_turn(axis: np.ndarray, deg: float) -> np.ndarray:
    """The rotation by `deg` about the unit `axis`."""
    return rotation_of(np.radians(deg) * np.asarray(axis, float))


def transformations_from_bop(
    info: dict, max_step: float = MAX_SYM_DISC_STEP
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The symmetry transformations of a `models_info.json` entry as BOP states them, offsets included
    (`from_bop` keeps the project's coarser form, which drops them: ~1.7 mm of MSSD on LM-O's eggbox and
    glue): each turn of the continuous symmetry (axis through its offset, sampled as `continuous_steps`)
    after each discrete one, identity first."""
    discrete = symmetry_transformations([m for m in info.get("symmetries_discrete") or []])
    continuous = info.get("symmetries_continuous") or []
    if len(continuous) > 1:
        raise ValueError("more than one continuous symmetry: BOP's errors define one at most")
    if not continuous:
        return discrete
    axis = np.asarray(continuous[0]["axis"], float)
    axis /= np.linalg.norm(axis)
    offset = np.asarray(continuous[0].get("offset", (0.0, 0.0, 0.0)), float)
    n = continuous_steps(max_step)
    turns = [_axis_turn(axis, 360.0 * i / n) for i in range(n)]
    # A turn about the axis through `offset`: x -> R (x - offset) + offset.
    return [(R @ D_R, R @ D_t - R @ offset + offset) for R in turns for D_R, D_t in discrete]
