"""BOP19 results files: one CSV row per pose estimate, the format the BOP challenge's evaluation reads.

    scene_id,im_id,obj_id,score,R,t,time

R is R_m2c row-major, 9 numbers separated by spaces; t is t_m2c, 3 numbers in mm (OpenCV camera axes,
`index.geometry.pose`); time is the seconds the method took on the whole image (the same on each of its rows),
-1 when unknown."""

from __future__ import annotations

import csv
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

HEADER = ("scene_id", "im_id", "obj_id", "score", "R", "t", "time")
#: BOP's "time unknown".
UNKNOWN_TIME = -1.0


@dataclass(frozen=True)
class Estimate:
    """One pose estimate: R (3, 3), t (3,) mm; time in seconds (-1: unknown)."""

    scene_id: int
    im_id: int
    obj_id: int
    score: float
    R: np.ndarray
    t: np.ndarray
    time: float = UNKNOWN_TIME


def _numbers(values: np.ndarray) -> str:
    # repr-exact floats, so that a file read back gives the same poses.
    return " ".join(repr(float(v)) for v in np.ravel(values))


def write_bop_csv(path: str | Path, estimates: Iterable[Estimate]) -> int:
    """Writes `estimates` to `path` (header first); returns how many rows."""
    n = 0
    with open(path, "w", newline="") as f:
        out = csv.writer(f, lineterminator="\n")
        out.writerow(HEADER)
        for e in estimates:
            R, t = np.asarray(e.R, float), np.asarray(e.t, float)
            if R.size != 9 or t.size != 3:
                raise ValueError(f"an estimate needs R of 9 numbers and t of 3; got {R.size} and {t.size}")
            out.writerow(
                [
                    e.scene_id,
                    e.im_id,
                    e.obj_id,
                    repr(float(e.score)),
                    _numbers(R),
                    _numbers(t),
                    repr(float(e.time)),
                ]
            )
            n += 1
    return n


def _parse(row: dict[str, str], line: int, path: Path) -> Estimate:
    try:
        R = np.array(row["R"].split(), float)
        t = np.array(row["t"].split(), float)
        if R.size != 9 or t.size != 3:
            raise ValueError(f"R has {R.size} numbers and t {t.size}; BOP needs 9 and 3")
        return Estimate(
            int(row["scene_id"]),
            int(row["im_id"]),
            int(row["obj_id"]),
            float(row["score"]),
            R.reshape(3, 3),
            t,
            float(row["time"]),
        )
    except (ValueError, TypeError, AttributeError) as err:
        raise ValueError(f"{path}:{line}: not a BOP19 results row ({err})") from None


def read_bop_csv(path: str | Path) -> list[Estimate]:
    """The estimates of a BOP19 results file; a malformed file raises ValueError naming the line."""
    path = Path(path)
    with open(path, newline="") as f:
        rows = csv.DictReader(f)
        if tuple(rows.fieldnames or ()) != HEADER:
            raise ValueError(f"{path}: the header must be {','.join(HEADER)}; got {rows.fieldnames}")
        return [_parse(row, i, path) for i, row in enumerate(rows, start=2)]
