"""How well objectness proposals find the annotated objects of BOP frames: each instance as a `Truth`, the rank of its first hit, and recall at k per tolerance (the objectness network's validation and `scripts/train_objectness.py`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from index.data.bop import Instance
from index.features.objectness import WINDOW_MM, Peak


@dataclass(frozen=True)
class Truth:
    """An annotated object of a frame: where its origin projects, its window and extent (px)."""

    u: float
    v: float
    window_px: float
    extent_px: float
    diameter_mm: float


def truth_of(inst: Instance, diameter_mm: float) -> Truth:
    """An annotated BOP instance as a `Truth` (its distance: the origin's, as the verifier's)."""
    d = float(np.linalg.norm(inst.t))
    f = (inst.K[0, 0] + inst.K[1, 1]) / 2
    return Truth(*inst.centre_uv, f * WINDOW_MM / d, f * diameter_mm / d, diameter_mm)


def hit_rank(
    proposals: Sequence[Peak], t: Truth, centre: float, scale: float, by_extent: bool = False
) -> int | None:
    """The rank (0 = best) of the first proposal within `centre` * window of the truth's origin whose
    window is within `scale` (relative) of the truth's; None if none is. `by_extent`: the window read from
    the extent and the true object's diameter, as the service does for each registered object."""
    for r, p in enumerate(proposals):
        w = p.extent_px * WINDOW_MM / t.diameter_mm if by_extent else p.window_px
        if np.hypot(p.u - t.u, p.v - t.v) <= centre * t.window_px and abs(w / t.window_px - 1) <= scale:
            return r
    return None


RECALL_KS = (5, 10, 20, 30)


# (name, centre tolerance as a share of the window, relative window tolerance): the verifier names the
# right object 97 % of the time at w/16 and 6 %, and falls to 10 % at w/8 or 12 %
TOLERANCES = (("w/16, 6%", 1 / 16, 0.06), ("w/8, 12%", 1 / 8, 0.12), ("w/4, 25%", 1 / 4, 0.25))


def recall(
    frames: Sequence[tuple[Sequence[Peak], Sequence[Truth]]], by_extent: bool = False
) -> dict[str, dict[str, float]]:
    """Share of the truths with a hit among the top k proposals of their frame, per tolerance and k."""
    n = sum(len(ts) for _, ts in frames)
    out: dict[str, dict[str, float]] = {}
    for name, c, s in TOLERANCES:
        ranks = [hit_rank(ps, t, c, s, by_extent) for ps, ts in frames for t in ts]
        out[name] = {
            f"top{k}": round(sum(r is not None and r < k for r in ranks) / max(n, 1), 4) for k in RECALL_KS
        }
    return out
