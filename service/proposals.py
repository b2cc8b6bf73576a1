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

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from index.depth_proposals import depth_proposals
from index.store import Snapshot
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
    the box it was seen in (x0, y0, x1, y1 px), its score (higher: more object-like) and its source."""

    u: float
    v: float
    distance_mm: float | None
    box: tuple[float, float, float, float]
    score: float
    source: str


def propose(
    d: Decoded, K: np.ndarray, colour: Colour | None, windows: Sequence[float], limit: int
) -> list[Proposal]:
    """At most `limit` proposals of each source for the decoded frame, best first. `windows`: the window
    classes (mm) among the registered objects; `colour` None when the service has no objectness model."""
    out: list[Proposal] = []
    if d.depth is not None:
        out += [
            Proposal(p.u, p.v, None, p.box, p.score, "depth")
            for p in depth_proposals(d.depth, K, limit=limit)
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
                # with depth, the pipeline measures the distance at the centre: no size is assumed
                distances = [None] if d.depth is not None else [focal * w / p.window_px for w in windows]
                out += [Proposal(p.u, p.v, dist, box, p.score, "colour") for dist in distances]
    return out


def windows_of(snap: Snapshot, default_mm: float) -> list[float]:
    """The window classes (mm) of the registered objects: each object's own (`extra["window_mm"]`), the
    model's (`default_mm`) for objects registered before windows followed sizes; the model's when none is
    registered."""
    found = {float(str(r.extra.get("window_mm", default_mm))) for r in snap.objects.values()}
    return sorted(found) or [default_mm]
