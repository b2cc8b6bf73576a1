"""The query's mask: with a model that has one (`index.features.embed.MASK_NAME`: a head on the trunk, or an RGB-D
model's depth), what is not the centred object is made black (colour) and empty (depth), as a template's
background is, before the descriptor and the local features read the patch."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from index.features.embed import Embedder
from index.features.patches import batch_inputs, fill_depth
from index.templates.register import TemplateConfig
from service.pipeline.context import Context
from service.pipeline.query import Decoded, Patches
from service.settings import Settings


class QueryMask:
    """The patches of the query's turns masked (`foreground`); in a pipeline only for a model with a mask.
    Nothing to configure: the model's mask decides."""

    name = "mask"

    @classmethod
    def build(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> QueryMask | None:
        return cls() if embedder.has_mask else None

    def __call__(self, ctx: Context) -> Context:
        assert ctx.patches is not None  # `Cut` ran
        described, keep = foreground(ctx.decoded, ctx.patches, ctx.window)
        return replace(ctx, described=described, keep=keep)


def foreground(d: Decoded, p: Patches, window_mm: float) -> tuple[Patches, np.ndarray]:
    """The query's patches with what the model's mask (`index.features.embed.MASK_NAME`) says is not the centred
    object black (colour) and empty (depth), as a template's background is, and that mask (N, S, S)
    bool. The descriptor and the local features then see the object, not what stands around it:
    measured on validation frames (docs/experiments.md), the rgb network within 20 deg 44 -> 50 % with its
    mask head against the same network re-ranked over template silhouettes only. The mask reads the depth
    as measured: a pixel without depth is not known to lie in an RGB-D model's band, so it is not the
    object's (filling first flooded a patch cut out on an empty background with the object's depth, and
    its mask with it). The depth's holes are then filled (`filled`) and what the mask empties stays empty.
    `window_mm`: the window the patches were cut through."""
    x = batch_inputs(d.modality, p.rgb, p.depth, p.distance, window_mm, fill=False)
    keep = d.embedder.mask(x)
    return masked(filled(p, keep), keep), keep


def filled(p: Patches, keep: np.ndarray | None = None) -> Patches:
    """The patches with their depth's holes filled (`index.features.patches.fill_depth`), as the network takes
    them. Before a mask: filling after it filled the emptied background from the object, 15 ms a query
    of the RGB-D re-ranking for nothing its network reads (measured on validation frames). `keep`: the mask
    (N, S, S) bool that will empty the rest: the fill stops once the holes inside it are filled."""
    return p if p.depth is None else replace(p, depth=fill_depth(p.depth, needed=keep))


def masked(p: Patches, keep: np.ndarray) -> Patches:
    """The patches black (colour) and empty (depth) where `keep` (N, S, S) bool is False."""
    rgb = None if p.rgb is None else p.rgb * keep[..., None].astype(p.rgb.dtype)
    depth = None if p.depth is None else np.where(keep, p.depth, 0.0).astype(np.float32)
    return replace(p, rgb=rgb, depth=depth)
