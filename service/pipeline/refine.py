"""The refinement: each of the best re-ranked candidates is also compared at the viewpoints next to its
own (the object's other templates within about one viewpoint step: `Viewpoints`) and at its roll turned
by a fraction of the templates' in-plane step either way (`REFINE_ROLL_DIVISOR`), and keeps the pose that
fits best.

Templates sit about 8 deg apart on the sphere (level 3; "around": within 1.5 times that) and 30 deg apart
in-plane (the shipped model), so an answer's pose is off by up to half of those; the local features of
every upright template are in memory already (`index.store.Snapshot`), so the other viewpoints cost a
comparison each, and a turned roll one more cut of the query. Measured on validation frames (docs/experiments.md)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from index.features.embed import Embedder
from index.geometry.pose import camera_centre, wrap_degrees
from index.templates.register import TemplateConfig
from service.pipeline.context import Context, Key
from service.pipeline.rerank import reranks
from service.settings import Settings

# The refinement's constants (`RefineConfig`), as the validation frames chose them; an experiment replaces
# them where the pipeline is built (a test's monkeypatch, a script's process), never through the settings.
#: the best answers refined. 10: chosen on the validation frames among 0, 5, 10, 20, 40 (docs/experiments.md:
#: 0 53.0, 10 62.6, 20 61.7 % within 20 deg; at five camera rolls 20 against 10 +0.5, interval -0.4 to +1.4)
ROLL_REFINE = 10
#: rounds, each from where the last left the answers, the roll's turn halved (a sixth of the in-plane step, a
#: twelfth, ...). 1: a second round, on the validation frames at five camera rolls with a re-ranking of 400,
#: made the pose finer (within 5 deg +4.8 points) but not more often within 20 deg (+2.3, interval 0.0 to +4.7)
#: for 4 ms a query more at 100 objects (docs/experiments.md)
REFINE_ROUNDS = 1
#: the nearest other viewpoints of an answer's object compared (within 1.5 neighbour steps). 6: an icosphere
#: viewpoint's ring of neighbours (5 or 6 at one step; `Viewpoints.near`); not tuned on its own, `ROLL_REFINE`
#: was chosen with it
NEAR_VIEWS = 6
#: an answer's roll is also tried turned by the templates' in-plane step divided by this, either way (halved
#: again each further round). 3: an answer's roll is off by up to half the step; its roll and +- a third of
#: the step put a candidate within a sixth of the step of any roll there (chosen with `ROLL_REFINE`)
REFINE_ROLL_DIVISOR = 3


@dataclass(frozen=True)
class Viewpoints:
    """One object's viewpoints that have local features: keys, unit directions (V, 3), and the typical
    angle between neighbours (deg; the median of each one's nearest other)."""

    keys: list[Key]
    directions: np.ndarray
    step_deg: float

    @classmethod
    def of(cls, keys: list[Key]) -> Viewpoints:
        directions = np.stack([camera_centre(k[1], k[2]) for k in keys])
        cos = directions @ directions.T
        np.fill_diagonal(cos, -1.0)
        step = (
            float(np.degrees(np.median(np.arccos(np.clip(cos.max(axis=1), -1.0, 1.0)))))
            if len(keys) > 1
            else 0.0
        )
        return cls(keys, directions, step)

    def near(self, key: Key, k: int, within: float = 1.5) -> list[Key]:
        """Up to `k` of the other viewpoints within `within` neighbour steps of `key`'s, nearest first."""
        cos = self.directions @ camera_centre(key[1], key[2])
        limit = np.cos(np.radians(within * self.step_deg))
        return [self.keys[i] for i in np.argsort(-cos)[: k + 1] if cos[i] >= limit and self.keys[i] != key][
            :k
        ]


class ViewpointTable:
    """Each object's `Viewpoints`, built once per snapshot's local features (a registration or deletion
    makes a new mapping, and so a new table) and kept for the last few mappings seen."""

    def __init__(self, keep: int = 4):
        self._tables: list[tuple[Mapping[Key, np.ndarray], dict[int, Viewpoints]]] = []
        self._keep = keep

    def of(self, local: Mapping[Key, np.ndarray]) -> dict[int, Viewpoints]:
        for mapping, table in self._tables:
            if mapping is local:
                return table
        by_object: dict[int, list[Key]] = {}
        for key in local:
            by_object.setdefault(key[0], []).append(key)
        table = {oid: Viewpoints.of(keys) for oid, keys in by_object.items()}
        self._tables = [(local, table), *self._tables][: self._keep]
        return table


@dataclass(frozen=True)
class RefineConfig:
    """`n`: the best candidates refined (`ROLL_REFINE`); `rounds` (`REFINE_ROUNDS`), each from where the last
    left them, the roll's turn halved; `near_views` (`NEAR_VIEWS`); `spacing`: the templates' in-plane step
    (0: upright only, no turn); the roll's turn in the first round is `spacing` / `roll_divisor`
    (`REFINE_ROLL_DIVISOR`)."""

    n: int
    rounds: int
    near_views: int
    spacing: float
    roll_divisor: int

    @classmethod
    def from_settings(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> RefineConfig:
        spacing = templates.inplane_spacing(embedder.info.inplane_step)
        return cls(ROLL_REFINE, REFINE_ROUNDS, NEAR_VIEWS, spacing, REFINE_ROLL_DIVISOR)


@dataclass(frozen=True)
class Refine:
    """The best `n` candidates compared also at the viewpoints around theirs and at their roll turned
    either way; each keeps the (viewpoint, roll) scoring best. A pose scored by an earlier stage is not
    scored again (the scorer keeps every score: `LocalScore`). Its viewpoint tables are built once per snapshot's local features."""

    name = "refine"

    config: RefineConfig
    tables: ViewpointTable = field(default_factory=ViewpointTable)

    @classmethod
    def build(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> Refine | None:
        on = reranks(settings, embedder) and ROLL_REFINE > 0
        return cls(RefineConfig.from_settings(settings, embedder, templates)) if on else None

    def __call__(self, ctx: Context) -> Context | None:
        r, scorer = ctx.ranked, ctx.scorer
        if r is None or scorer is None:  # nothing re-ranked
            return None
        c = self.config
        table = self.tables.of(scorer.local)
        score, keys, rolls = r.scores.copy(), list(r.keys), list(r.rolls)
        best = np.argsort(score, kind="stable")[: c.n]
        for step in range(c.rounds):  # each round from where the last left each candidate, the turn halved
            turn = c.spacing / (c.roll_divisor * 2**step)
            turns = (0.0, -turn, turn) if c.spacing > 0 else (0.0,)
            tried: list[tuple[int, Key, float]] = []
            for j in best:
                views = [keys[j], *table[keys[j][0]].near(keys[j], c.near_views)]
                for o in turns:
                    roll = round(float(wrap_degrees(rolls[j] + o)), 3)
                    tried += [(int(j), v, roll) for v in views if (v, roll) != (keys[j], rolls[j])]
            # a pose an earlier stage or candidate scored is not scored again (`LocalScore`)
            got = scorer.pairs([(v, roll) for _, v, roll in tried])
            for (j, v, roll), s in zip(tried, got, strict=True):
                if s < score[j]:
                    score[j], keys[j], rolls[j] = s, v, roll
        score.flags.writeable = False
        ranked = replace(r, scores=score, keys=tuple(keys), rolls=tuple(rolls))
        return replace(ctx, ranked=ranked)
