"""Object symmetries: the turns of an object that leave it looking the same (the pose errors that forgive
them are `index.geometry.pose_error`'s).

A symmetry is named by its turns about the object's z axis, and, after "+flip" (or "flip" alone), a
half-turn about an axis across z, through the object's centre, that turns the object end over end:
- "none", "180" (a half-turn about z: LineMOD's eggbox and glue), "full" (any turn about z: a bowl);
- "flip": a half-turn about the x axis, its ends alike;
- "180+flip": a box, half-turns about z, x and y;
- "full+flip": a can whose two ends look alike (any turn about z, and end over end);
- "@<degrees>" after the flip: its axis that many degrees from x in the xy plane (a box whose sides are
  not along its mesh's x and y axes: "180+flip@28");
- "x:" or "y:" before the name: the same about the mesh's x or y axis in place of z ("y:full+flip", a pen
  lying along y), the flip's angle then measured from y or z (the axes x, y, z turned so that z goes there).
The turns are about axes through the object's centre (`centre`, mm; the origin when not given: the
service's poses need only the rotations). BOP's `symmetries_discrete` 4x4 matrices and
`symmetries_continuous` are read into these names where they are such turns (`from_bop`), into a list of
rotations otherwise; `bop_form` states a name in BOP's form.
`symmetry_transformations` gives the (R, t) transformations BOP's MSSD and MSPD minimise over.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from index.geometry.pose import rotation_of

#: the named symmetries (a flip's axis other than x: "@<degrees>" after the name; "x:" or "y:" before it
#: for the mesh's x or y axis in place of z)
SYMMETRIES = ("none", "180", "full", "flip", "180+flip", "full+flip")
Symmetry = str | Sequence[np.ndarray]  # a name, or BOP's discrete rotations

_NAME = re.compile(r"^(?:([xyz]):)?(?:(none|180|full)|(?:(180|full)\+)?flip(?:@(-?\d+(?:\.\d+)?))?)$")
#: the frame that takes z to each axis (columns: where x, y, z go), a cyclic turn of the axes
_FRAMES = {
    "z": np.eye(3),
    "x": np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
    "y": np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
}


@dataclass(frozen=True)
class Named:
    """A named symmetry: its turns about its axis ("none", "180" or "full"), its flip's axis, degrees in the plane
    across it (None: no flip), brought to its smallest equivalent ([0, 180), [0, 90) with "180", 0 with
    "full"), and the mesh's axis it is about ("z", or "x" or "y": `_FRAMES`)."""

    about_z: str
    flip_deg: float | None = None
    axis: str = "z"

    def __post_init__(self) -> None:
        if self.flip_deg is not None:
            period = {"none": 180.0, "180": 90.0, "full": None}[self.about_z]
            deg = 0.0 if period is None else round(float(self.flip_deg) % period, 1) % period
            object.__setattr__(self, "flip_deg", deg)

    @property
    def name(self) -> str:
        if self.flip_deg is None:
            stem = self.about_z
        else:
            stem = "flip" if self.about_z == "none" else f"{self.about_z}+flip"
            stem = stem if self.flip_deg == 0 else f"{stem}@{self.flip_deg:g}"
        return stem if self.axis == "z" else f"{self.axis}:{stem}"

    @property
    def continuous(self) -> bool:
        return self.about_z == "full"

    @property
    def frame(self) -> np.ndarray:
        """The rotation that takes z to the symmetry's axis (`_FRAMES`)."""
        return _FRAMES[self.axis]


def parse(symmetry: str) -> Named:
    """The named symmetry `symmetry` (see the module's docstring); ValueError for a name that is not one."""
    m = _NAME.match(symmetry.strip()) if isinstance(symmetry, str) else None
    if m is None:
        raise ValueError(
            f"unknown symmetry {symmetry!r}; use one of {', '.join(SYMMETRIES)} "
            "(a flip about an axis other than x: '@<degrees from x>' after it, e.g. '180+flip@30'; about the "
            "mesh's x or y axis in place of z: 'x:' or 'y:' before it)"
        )
    axis = m.group(1) or "z"
    if m.group(2):
        return Named(m.group(2), None, axis)
    return Named(m.group(3) or "none", float(m.group(4) or 0.0), axis)


def canonical(symmetry: str) -> str:
    """`symmetry`'s name in its smallest form ("180+flip@90" is "180+flip", "x:180" is "flip": z first);
    ValueError if it is none."""
    named = parse(symmetry)
    if named.axis == "z" or named.continuous:
        return named.name
    return _named_discrete(_group(named, 1)[1:]) or named.name


def continuous(symmetry: Symmetry) -> Named | None:
    """The named symmetry when `symmetry` is one with any turn about its axis (errors treat it exactly)."""
    if not isinstance(symmetry, str):
        return None
    named = parse(symmetry)
    return named if named.continuous else None


def turns_over(symmetry: str) -> bool:
    """Whether one of the symmetry's turns takes the mesh's z axis to -z: the object seen from below its xy
    plane is then the object seen from above, turned."""
    return any(S[2, 2] < -1.0 + 1e-6 for S in _group(parse(symmetry), 4))


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def flip_rotation(deg: float) -> np.ndarray:
    """The half-turn about the axis in the xy plane `deg` degrees from x."""
    a = np.array([np.cos(np.radians(deg)), np.sin(np.radians(deg)), 0.0])
    return 2.0 * np.outer(a, a) - np.eye(3)


def _group(named: Named, full_steps: int) -> list[np.ndarray]:
    """The rotations of a named symmetry, identity first; "full" sampled in `full_steps` equal turns."""
    n = {"none": 1, "180": 2, "full": full_steps}[named.about_z]
    turns = [_rot_z(360.0 * i / n) for i in range(n)]
    if named.flip_deg is not None:
        flip = flip_rotation(named.flip_deg)
        turns += [Z @ flip for Z in turns]
    P = named.frame
    return [P @ S @ P.T for S in turns]


def symmetry_rotations(symmetry: Symmetry) -> list[np.ndarray]:
    """Object-frame rotations S that leave the object looking the same (identity first).

    "full" is sampled every 1°; `index.geometry.pose_error` treats it exactly."""
    if not isinstance(symmetry, str):
        return [np.eye(3)] + [np.asarray(S, float)[:3, :3] for S in symmetry]
    return _group(parse(symmetry), 360)


def _flip_deg(R: np.ndarray, atol: float = 0.05) -> float | None:
    """The axis of `R` (degrees from x in the xy plane) when it is a half-turn about an axis across z."""
    if abs(R[2, 2] + 1.0) > atol or abs(np.trace(R) + 1.0) > atol:
        return None
    axis_outer = (R + np.eye(3)) / 2.0  # a a^T for a half-turn about a
    j = int(np.argmax(np.diag(axis_outer)))
    a = axis_outer[:, j] / np.sqrt(max(axis_outer[j, j], 1e-12))
    return float(np.degrees(np.arctan2(a[1], a[0])) % 180.0)


def _named_discrete(rotations: Sequence[np.ndarray], atol: float = 0.05) -> str | None:
    """The name of a set of discrete rotations (identity left out) when it is one, else None: about z
    first, then about x and y."""
    for axis, P in _FRAMES.items():
        local = [P.T @ R @ P for R in rotations]
        z180 = any(np.allclose(R, _rot_z(180.0), atol=atol) for R in local)
        flips = [d for d in (_flip_deg(R, atol) for R in local) if d is not None]
        named = Named("180" if z180 else "none", flips[0] if flips else None, axis)
        expected = _group(named, 1)[1:]
        if not expected or len(expected) != len(rotations):
            continue
        if all(any(np.allclose(R, E, atol=atol) for R in rotations) for E in expected):
            return named.name
    return None


def from_bop(info: dict) -> str | list[np.ndarray]:
    """The symmetry of a `models_info.json` entry: a name where its turns are a named symmetry's (offsets
    aside: they move the object, not how it looks from a turned camera), else its rotations (BOP's 4x4
    matrices; a continuous symmetry about an axis that is none of the mesh's, sampled every degree)."""
    mats = [np.asarray(m, float).reshape(4, 4) for m in info.get("symmetries_discrete") or []]
    if turning := info.get("symmetries_continuous"):
        a = np.asarray(turning[0]["axis"], float)
        a /= np.linalg.norm(a)
        for axis, P in _FRAMES.items():
            if abs(a @ P[:, 2]) > 0.999:
                flipped = any(_flip_deg(P.T @ m[:3, :3] @ P) is not None for m in mats)
                return Named("full", 0.0 if flipped else None, axis).name
        turns = [_axis_turn(a, deg) for deg in range(360)]
        return [T @ D for T in turns for D in [np.eye(3)] + [m[:3, :3] for m in mats]][1:]
    if not mats:
        return "none"
    named = _named_discrete([m[:3, :3] for m in mats])
    return named if named is not None else mats


def _about(R: np.ndarray, centre: np.ndarray) -> list[float]:
    """The 4x4 of the turn R about `centre` (x -> R (x - c) + c), as BOP lists it."""
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = R, centre - R @ centre
    return m.ravel().tolist()


def bop_form(symmetry: str, centre: Sequence[float] | None = None) -> dict:
    """A named symmetry as `models_info.json` states it (`from_bop`'s inverse), its turns about axes through
    `centre` (mm; the origin when None): the keys to add."""
    named, c = parse(symmetry), _centre(centre)
    out: dict = {}
    if named.continuous:
        P = named.frame
        out["symmetries_continuous"] = [{"axis": P[:, 2].tolist(), "offset": c.tolist()}]
        discrete = [] if named.flip_deg is None else [P @ flip_rotation(named.flip_deg) @ P.T]
    else:
        discrete = _group(named, 1)[1:]
    if discrete:
        out["symmetries_discrete"] = [_about(R, c) for R in discrete]
    return out


def _centre(centre: Sequence[float] | None) -> np.ndarray:
    return np.zeros(3) if centre is None else np.asarray(centre, float).reshape(3)


#: BOP's rule for discretising a continuous symmetry: no model point may move more than this fraction of
#: the object's diameter between two neighbouring samples (bop_toolkit's default `max_sym_disc_step`).
MAX_SYM_DISC_STEP = 0.01


def continuous_steps(max_step: float = MAX_SYM_DISC_STEP) -> int:
    """How many equal turns sample a full turn about an axis so that no point moves more than `max_step`
    diameters between neighbours: a point at most d/2 from the axis moves d·sin(π/n) ≤ d·π/n per step."""
    return int(np.ceil(np.pi / max_step))


def symmetry_transformations(
    symmetry: Symmetry, max_step: float = MAX_SYM_DISC_STEP, centre: Sequence[float] | None = None
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The object-frame transformations x -> R x + t (t in mm) that leave the object looking the same,
    identity first, as BOP's model-based errors (MSSD, MSPD) minimise over them.

    A name's turns are about axes through `centre` (the origin when None), "full" sampled by BOP's
    max-distance rule (`continuous_steps`); BOP's discrete 4x4 matrices keep their translation offsets."""
    if not isinstance(symmetry, str):
        mats = [np.asarray(m, float) for m in symmetry]
        mats = [m.reshape(4, 4) if m.size == 16 else m.reshape(3, 3) for m in mats]
        return [(np.eye(3), np.zeros(3))] + [(m[:3, :3], _offset(m)) for m in mats]
    c = _centre(centre)
    return [(R, c - R @ c) for R in _group(parse(symmetry), continuous_steps(max_step))]


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
