"""Where in a whole frame an object may be, before anything names it: the detection's proposals
(`service.detection` verifies each).

- colour: the objectness network (`index.objectness`, `models/posedesc-objectness.onnx`): object centres
  and how large each object looks, over an image pyramid. How large it looks is the side of its window
  in px, so each window class among the registered objects puts it at its own distance (fx * window mm /
  window px);
- depth: what stands on the support, segmented (`index.depth_proposals`), at the distance it is measured.

With both (RGB-D), both kinds are verified, the depth's first: where depth saw something, its distance
is measured rather than inferred from a size."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from index.depth_proposals import depth_proposals
from service.errors import ApiError
from service.pipeline.query import Decoded


class Seen(Protocol):
    """A colour proposal as the objectness network gives it (`index.objectness.Proposal`): the centre
    (px), the side of the object's model window there (px) and its score."""

    @property
    def u(self) -> float: ...
    @property
    def v(self) -> float: ...
    @property
    def window_px(self) -> float: ...
    @property
    def score(self) -> float: ...


#: colour proposals of a frame: (rgb (H, W, 3) uint8, limit) -> the best `limit`, best first
Colour = Callable[[np.ndarray, int], Sequence[Seen]]


@dataclass(frozen=True)
class Proposal:
    """A place to verify: the centre (px), the distance to cut at (mm; None: measured from depth there),
    the box it was seen in (x0, y0, x1, y1 px), its score (higher: more object-like), its source, and the
    objects it is verified against (None: all; a colour proposal's distance holds for one window class)."""

    u: float
    v: float
    distance_mm: float | None
    box: tuple[float, float, float, float]
    score: float
    source: str
    objects: frozenset[int] | None = None


def propose(
    d: Decoded,
    K: np.ndarray,
    colour: Colour | None,
    windows: Mapping[float, frozenset[int]],
    limit: int,
    depth_limit: int,
) -> list[Proposal]:
    """At most `limit` colour proposals and `depth_limit` depth ones for the decoded frame, best first.
    `windows`: the window classes (mm) among the registered objects, and their objects
    (`index.windows.window_classes`); `colour` None when the service has no objectness model."""
    out: list[Proposal] = []
    if d.depth is not None:
        out += [
            Proposal(p.u, p.v, None, p.box, p.score, "depth")
            for p in depth_proposals(d.depth, K, limit=depth_limit)
        ]
    if d.rgb is not None:
        if colour is None:
            if d.depth is None:
                raise ApiError(
                    422,
                    "this service has no objectness model (posedesc-objectness.onnx in its models dir) to find "
                    "objects in a colour frame: send u and v (and distance_mm), or depth",
                )
        else:
            focal = (K[0, 0] + K[1, 1]) / 2
            for p in colour(d.rgb, limit):
                half = p.window_px / 2
                box = (p.u - half, p.v - half, p.u + half, p.v + half)
                if d.depth is not None:  # the pipeline measures the distance at the centre: no size assumed
                    out.append(Proposal(p.u, p.v, None, box, p.score, "colour"))
                    continue
                # the network's window is of an object filling it as the model's objects fill theirs: an
                # object of another class looking that large is as much nearer or farther as its window
                one = len(windows) <= 1
                out += [
                    Proposal(p.u, p.v, focal * w / p.window_px, box, p.score, "colour", None if one else ids)
                    for w, ids in windows.items()
                ]
    return out
