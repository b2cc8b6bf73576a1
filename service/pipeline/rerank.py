"""The first re-ranking pass (timed as `local`): the search's candidates that have local features scored
by the local score (`service.pipeline.score`), each against the query turned upright at its own roll.
The later passes (`sweep`, `refine`) start from these scores and the scorer this stage hands on."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from index.features.embed import Embedder
from index.store import Match, local_key
from index.store.search import Nearest
from index.templates.register import TemplateConfig
from service.pipeline.context import Context, Key, Ranked
from service.pipeline.score import LocalScore, QueryCuts, ScoreConfig
from service.rejection import served_score
from service.settings import Settings


def reranks(settings: Settings, embedder: Embedder) -> bool:
    """Whether the pipeline of this model re-ranks at all: a model with local features, `rerank` > 0 (the
    answers' distances are then the local score: `service.rejection.served_score`)."""
    return served_score(settings, embedder) == "local"


def keys_and_rolls(matches: Sequence[Match]) -> tuple[list[Key], list[float]]:
    """Each match's viewpoint as its local features are found (`local_key`) and its roll to 1e-3 degrees:
    read from the search's arrays (`index.store.search.Nearest`) when it gave them."""
    if isinstance(matches, Nearest):
        return matches.keys(), matches.rolls()
    keys = [local_key(m.object_id, m.azimuth, m.elevation) for m in matches]
    return keys, [round(m.inplane, 3) for m in matches]


@dataclass(frozen=True)
class RerankConfig:
    """`score`: how a pose is scored; `patch_distance_mm`: as the query's cut takes it."""

    score: ScoreConfig
    patch_distance_mm: float

    @classmethod
    def from_settings(cls, settings: Settings) -> RerankConfig:
        return cls(ScoreConfig.from_settings(settings), settings.patch_distance_mm)


@dataclass(frozen=True)
class Rerank:
    """The candidates re-ranked by local similarity: the query is cut once per roll the candidates give
    (turned upright for each), and each candidate's upright template compared with it (`LocalScore`).
    A candidate whose viewpoint has no local features keeps its place after those that have (the
    answers' assembly, `service.pipeline.answer`). Measured on validation frames (docs/experiments.md)."""

    name = "local"

    config: RerankConfig

    @classmethod
    def build(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> Rerank | None:
        return cls(RerankConfig.from_settings(settings)) if reranks(settings, embedder) else None

    def __call__(self, ctx: Context) -> Context | None:
        d, p = ctx.decoded, ctx.patches
        local = ctx.snapshot.models[d.modality].local
        if not local:  # a store without local features: the descriptor's answers stand
            return None
        assert p is not None  # `Cut` ran
        mask = None if ctx.keep is None else (float(p.offsets[0]), ctx.keep[0])
        cuts = QueryCuts(ctx.query, d, mask, self.config.patch_distance_mm, ctx.window)
        # the relief's clip, `relief_clip_mm` at the model's window, scales with the window the query is
        # cut through: the same share of it, whatever the class (the relief is measured in windows)
        scorer = LocalScore(self.config.score, cuts, local, d.embedder.local_grid, d.embedder.info.window_mm)
        ctx = replace(ctx, scorer=scorer, score="local")
        every, all_rolls = keys_and_rolls(ctx.matches)
        have = tuple(i for i, k in enumerate(every) if k in local)
        if not have:
            return ctx
        keys = tuple(every[i] for i in have)
        rolls = tuple(all_rolls[i] for i in have)
        first = tuple(zip(keys, rolls, strict=True))
        scores = scorer.pairs(first)
        scores.flags.writeable = False  # the context is frozen: a later stage scores a copy
        return replace(ctx, ranked=Ranked(have, keys, rolls, scores, first))
