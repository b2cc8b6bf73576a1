"""The descriptor's stages: the query's patches embedded in one batch (`Embed`), and the store searched
for the nearest distinct (object, viewpoint) answers over every in-plane variant and query turn
(`Search`). The search runs on the snapshot the query started with, never waiting on a registration."""

from __future__ import annotations

from dataclasses import dataclass, replace

from index.features.embed import Embedder
from index.store import Snapshot
from index.templates.register import TemplateConfig
from service.pipeline.context import Context
from service.pipeline.query import untextured
from service.settings import Settings


class Embed:
    """The descriptors of the query's patches (as masked), one batch for all its turns. Nothing to
    configure: the model decides."""

    name = "embed"

    @classmethod
    def build(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> Embed:
        return cls()

    def __call__(self, ctx: Context) -> Context:
        p = ctx.described
        assert p is not None  # `Cut` ran
        # a masked query's depth was filled before the mask emptied the rest (`service.pipeline.mask`)
        desc = ctx.decoded.embedder.embed_patches(
            p.rgb, p.depth, p.distance, fill=ctx.keep is None, window_mm=ctx.window
        )
        return replace(ctx, descriptors=desc)


@dataclass(frozen=True)
class SearchConfig:
    """`variants`: in-plane templates a viewpoint has (what the answers collapse); `rerank`: the answers
    the re-ranking takes (`Settings.rerank`, 0 for a model without local features), asked of the store
    instead of k when more and the store holds local features."""

    variants: int
    rerank: int
    handicap: float = 0.0

    @classmethod
    def from_settings(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> SearchConfig:
        variants = len(templates.inplane(embedder.info.inplane_step))
        return cls(variants, settings.rerank if embedder.has_local else 0, settings.shape_handicap)


@dataclass(frozen=True)
class Search:
    """The nearest distinct answers: as many as are wanted (`Context.wanted`), or as the re-ranking takes."""

    name = "search"

    config: SearchConfig

    @classmethod
    def build(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> Search:
        return cls(SearchConfig.from_settings(settings, embedder, templates))

    def __call__(self, ctx: Context) -> Context:
        assert ctx.descriptors is not None and ctx.patches is not None  # `Embed` ran
        m = ctx.decoded.modality
        rerank = self.config.rerank if ctx.snapshot.models[m].local else 0
        # a snapshot within a window class's objects (`service.pipeline.Pipeline`) searches theirs only
        found = ctx.snapshot.answers(
            m,
            ctx.descriptors,
            max(ctx.wanted, rerank),
            ctx.patches.offsets,
            self.config.variants,
            weights=shape_weights(ctx.snapshot, self.config.handicap) if m != "depth" else None,
        )
        return replace(ctx, matches=found)


def shape_weights(snapshot: Snapshot, handicap: float) -> dict[int, float]:
    """1 + `handicap` for each shape-only object (`untextured`): the weight of its distances when the
    candidates are chosen in colour, as `service.pipeline.answer.handicapped` weighs the answers; none when
    every object is shape-only (the same weight for all changes no order)."""
    if handicap <= 0:
        return {}
    weights = {o: 1.0 + handicap for o, rec in snapshot.objects.items() if untextured(rec)}
    # all alike: the plain order, at the plain cost
    return weights if len(weights) < len(snapshot.objects) else {}
