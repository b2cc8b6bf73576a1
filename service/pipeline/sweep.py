"""The roll sweep: the best re-ranked candidates compared also at every other in-plane angle of the
templates, each keeping the roll that scores best. The descriptor gives each viewpoint one roll, its
nearest variant's, and for an occluded object that roll is often wrong where the viewpoint is right
(docs/experiments.md)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from index.features.embed import Embedder
from index.geometry.pose import wrap_degrees
from index.templates.register import TemplateConfig
from service.pipeline.context import Context
from service.pipeline.rerank import reranks
from service.settings import Settings


@dataclass(frozen=True)
class SweepConfig:
    """`n`: the best candidates swept (`Settings.roll_sweep`); `angles`: the templates' in-plane angles."""

    n: int
    angles: tuple[float, ...]

    @classmethod
    def from_settings(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> SweepConfig:
        angles = templates.inplane(embedder.info.inplane_step)
        return cls(settings.roll_sweep, tuple(float(a) for a in angles))


@dataclass(frozen=True)
class Sweep:
    """Each of the best `n` candidates at every template angle shifted by its own offset from its
    nearest angle (a turn of the query's), each template read once for all of them (`LocalScore.table`).
    The query's cuts at those rolls are mostly made already: the re-ranking's candidates span the turn."""

    name = "sweep"

    config: SweepConfig

    @classmethod
    def build(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> Sweep | None:
        config = SweepConfig.from_settings(settings, embedder, templates)
        on = reranks(settings, embedder) and config.n > 0 and len(config.angles) > 1
        return cls(config) if on else None

    def __call__(self, ctx: Context) -> Context | None:
        r, scorer = ctx.ranked, ctx.scorer
        if r is None or scorer is None:  # nothing re-ranked
            return None
        turns = np.asarray(self.config.angles, float)
        best = np.argsort(r.scores, kind="stable")[: self.config.n]
        by_gap: dict[float, list[int]] = {}  # candidates by their offset from the nearest angle
        offsets = np.asarray(wrap_degrees(np.asarray(r.rolls, float)[best, None] - turns[None]))
        nearest = offsets[np.arange(len(best)), np.argmin(np.abs(offsets), axis=1)]
        for j, off in zip(best, nearest, strict=True):
            by_gap.setdefault(round(float(off), 3), []).append(int(j))
        score, rolls = r.scores.copy(), list(r.rolls)
        for gap, group in by_gap.items():
            turned = sorted({round(float(wrap_degrees(a + gap)), 3) for a in turns})
            table = scorer.table([r.keys[j] for j in group], turned)
            at = np.argmin(table, axis=1)
            for j, i, s in zip(group, at, table[np.arange(len(group)), at], strict=True):
                if s < score[j]:
                    score[j], rolls[j] = s, turned[i]
        score.flags.writeable = False
        ranked = replace(r, scores=score, rolls=tuple(rolls))
        return replace(ctx, ranked=ranked)
