"""What one query carries through the pipeline (`Context`, frozen: each stage hands on a new one) and
what a stage is (`Stage`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Protocol

import numpy as np

from index.store import Match, Snapshot

if TYPE_CHECKING:
    from service.pipeline.query import Decoded, Patches, Query
    from service.pipeline.score import LocalScore

Key = tuple[int, float, float]  # `index.store.local_key`: object, azimuth, elevation
Pose = tuple[Key, float]  # a viewpoint and a roll (degrees, rounded to 3 decimals)


@dataclass(frozen=True)
class Ranked:
    """The candidates the re-ranking scored: `have`, their places among the search's matches (those whose
    viewpoint has local features); `keys`, `rolls`, `scores` (N,) their poses and local scores as the
    stages so far left them; `first` their poses as the search gave them."""

    have: tuple[int, ...]
    keys: tuple[Key, ...]
    rolls: tuple[float, ...]
    scores: np.ndarray
    first: tuple[Pose, ...]


@dataclass(frozen=True)
class Context:
    """One query in the pipeline. `snapshot`: the store as the query found it, for all its stages.
    `patches`: the query cut at its turns (the depth as measured); `described`: those patches as the
    descriptor sees them (masked: `service.pipeline.mask`), `keep` (n, S, S) bool that mask or None;
    `matches`: the search's candidates; `ranked`: the local scores, once re-ranked; `scored`: every pose
    scored so far (the same template against the same cut of the query scores the same, so none is scored
    twice); `scorer`: the re-ranking's score of this query (holding the query's cuts, made once per
    roll); `score`: what the answers' distances are ("local" once re-ranked); `wanted`: how many answers
    are ranked, k or more when the open-set verdict reads past the best (`service.rejection.LISTED`)."""

    query: Query
    decoded: Decoded
    snapshot: Snapshot
    patches: Patches | None = None
    described: Patches | None = None
    keep: np.ndarray | None = None
    descriptors: np.ndarray | None = None
    matches: tuple[Match, ...] = ()
    ranked: Ranked | None = None
    scored: Mapping[Pose, float] = field(default_factory=lambda: MappingProxyType({}))
    scorer: LocalScore | None = None
    score: str = "descriptor"
    wanted: int = 0


class Stage(Protocol):
    """One step of the pipeline: `name` is its entry in `timings_ms`; a call returns the context handed
    on, or None when the stage has nothing to do for this query (no entry then)."""

    name: str

    def __call__(self, ctx: Context) -> Context | None: ...
