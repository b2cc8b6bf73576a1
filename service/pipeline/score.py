"""The re-ranking's score, one implementation for every stage that scores a pose (`rerank`, `sweep`,
`refine`): a stored template's local features (`index.embed.LOCAL_NAME`, the pretrained trunk's map)
against the query's, cut upright at the pose's roll, cell by cell where the object is
(`index.local.masked_distance`: the template's silhouette, and the query's mask when the model has one),
plus with depth the distance of their reliefs (`index.local.relief_distance`, weighed by
`relief_weight`). Templates stored without silhouettes (older stores) are compared as whole maps (`l2`).

Two shapes of one score: `pairs` (each template at its own roll) and `table` (every template at every one
of some rolls). They share every step but the cells' cosines, where each has its kernel: pairs one query
row per template (`index.local.cell_cosines`), the table one small matrix product per cell
(`index.local.cell_cosines_across`, so a template read once serves every roll). Measured on the real
rows here (out of process, one thread): 400 pairs over 12 rolls 6.7 ms by the pair kernel, 9.8 ms by the
table kernel one roll at a time, 47.7 ms as a gather from the whole table."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from index.local import (
    StoredLocal,
    cell_cosines,
    cell_cosines_across,
    cell_weights,
    l2,
    masked_distance,
    relief,
    relief_distance,
)
from index.patches import batch_inputs, turn_masks
from service.pipeline.context import Key, Pose
from service.pipeline.mask import filled, foreground, masked
from service.pipeline.query import Decoded, Query, cut
from service.settings import Settings


@dataclass(frozen=True)
class ScoreConfig:
    """`coverage`: `index.local.masked_distance`'s weight of the query's mask left outside a template's
    silhouette (`Settings.mask_coverage`). `relief`: the weight of `index.local.relief_distance` added
    where both have depth (`Settings.relief_weight`), its residuals clipped at `relief_clip_mm`."""

    coverage: float
    relief: float
    relief_clip_mm: float

    @classmethod
    def from_settings(cls, settings: Settings) -> ScoreConfig:
        return cls(settings.mask_coverage, settings.relief_weight, settings.relief_clip_mm)


@dataclass(frozen=True)
class RollCut:
    """The query cut upright at one roll, as the score compares it: the local features (F,), its mask
    (S, S) bool or None, and its relief (`index.local.relief`: values and shares, (G * G,) each) or None
    without depth."""

    features: np.ndarray
    mask: np.ndarray | None
    relief: tuple[np.ndarray, np.ndarray] | None


class QueryCuts:
    """The query's cuts by roll, each made once for the whole query: every stage asks again for rolls an
    earlier one cut. `mask`: (in-plane, mask (S, S)) of the query cut at that in-plane, as the mask stage
    found it: turned to each roll (`turn_masks`) rather than found again, which would run the mask head
    once a roll. `patch_distance_mm`: as `service.pipeline.query.cut` takes it; `window_mm`: the window
    the query is cut through (its objects' class, `index.windows`; None: the model's)."""

    def __init__(
        self,
        q: Query,
        d: Decoded,
        mask: tuple[float, np.ndarray] | None,
        patch_distance_mm: float,
        window_mm: float | None = None,
    ):
        self._q, self._d, self._mask, self._patch_mm = q, d, mask, patch_distance_mm
        self._window = d.embedder.info.window_mm if window_mm is None else window_mm
        self._cuts: dict[float, RollCut] = {}

    def at(self, rolls: Sequence[float]) -> list[RollCut]:
        """The cuts at `rolls` (degrees, 3 decimals), those missing made in one batch."""
        if missing := sorted(set(rolls) - self._cuts.keys()):
            self._cuts |= self._make(missing)
        return [self._cuts[r] for r in rolls]

    def _make(self, rolls: list[float]) -> dict[float, RollCut]:
        q, d, mask, window = self._q, self._d, self._mask, self._window
        spec = replace(d.embedder.info.spec, window_mm=window)
        # undoes each roll: the object upright
        p = cut(q, d.rgb, d.depth, spec, rolls, patch_distance_mm=self._patch_mm)
        keep = None
        if mask is not None:
            keep = np.stack([turn_masks(mask[1][None], r - mask[0], spec)[0] for r in rolls])
            p = masked(filled(p), keep)
        elif d.embedder.has_mask:
            p, keep = foreground(d, p, window)
        x = batch_inputs(d.modality, p.rgb, p.depth, p.distance, window, fill=keep is None)
        shapes = None
        if p.depth is not None:  # the depth as cut (holes filled, emptied outside the mask): its relief
            distance = np.full(len(rolls), p.distance, np.float32)
            shapes = relief(p.depth, distance, d.embedder.local_grid, window, keep)
        out = {}
        for i, (r, f) in enumerate(zip(rolls, d.embedder.local(x), strict=True)):
            reliefs = None if shapes is None else (shapes[0][i], shapes[1][i])
            out[r] = RollCut(f, None if keep is None else keep[i], reliefs)
        return out


@dataclass(frozen=True)
class LocalScore:
    """The score of stored templates (`local`: the snapshot's local features by viewpoint) against this
    query's cuts (`cuts`), as `config` says. `window_mm`: the model's; the relief's clip is
    `relief_clip_mm` / `window_mm` windows whatever window the query is cut through: `relief_clip_mm` is
    the clip at the model's window, and scales with an object's (`index.windows`)."""

    config: ScoreConfig
    cuts: QueryCuts
    local: Mapping[Key, np.ndarray]
    grid: int
    window_mm: float

    def pairs(self, poses: Sequence[Pose]) -> np.ndarray:
        """Each pose's score: its viewpoint's template against the query cut at its roll. Shape: (N,)."""
        rolls = [r for _, r in poses]
        distinct = sorted(set(rolls))
        query = self.cuts.at(distinct)
        where = {r: i for i, r in enumerate(distinct)}
        order = np.argsort([where[r] for r in rolls], kind="stable")  # one roll's templates side by side
        row = np.array([where[rolls[i]] for i in order], int)
        feats = np.stack([c.features for c in query])
        stored = self._stored([poses[i][0] for i in order], feats.shape[1])
        if stored.silhouettes is None:  # no silhouettes stored
            score = l2(feats[row], stored.features)
        else:
            cos = cell_cosines(feats, stored.features, self.grid, row)
            score = self._distance(cos, stored, query, row)
        out = np.empty_like(score)
        out[order] = score
        return out

    def table(self, keys: Sequence[Key], rolls: Sequence[float]) -> np.ndarray:
        """Every viewpoint's template (`keys`) against the query cut at every one of `rolls`, each
        template read once. Shape: (N, R)."""
        query = self.cuts.at(rolls)
        feats = np.stack([c.features for c in query])
        stored = self._stored(keys, feats.shape[1])
        if stored.silhouettes is None:  # no silhouettes stored: the pairs one by one
            return self.pairs([(k, r) for k in keys for r in rolls]).reshape(len(keys), len(rolls))
        cos = cell_cosines_across(feats, stored.features, self.grid)
        return self._distance(cos, stored, query, None)

    def _stored(self, keys: Sequence[Key], features: int) -> StoredLocal:
        return StoredLocal.of(np.stack([np.asarray(self.local[k]) for k in keys]), features, self.grid)

    def _distance(
        self, cos: np.ndarray, stored: StoredLocal, query: list[RollCut], row: np.ndarray | None
    ) -> np.ndarray:
        """The score from the cells' cosines: of pairs (`row`: each template's query row; cos (N, G * G))
        or of the table (`row` None; cos (N, R, G * G)), by one formula whose arrays broadcast."""
        assert stored.silhouettes is not None
        c, pairs = self.config, row is not None

        def templates(x: np.ndarray) -> np.ndarray:  # (N, G * G), or (N, 1, G * G) against every row
            return x if pairs else x[:, None]

        def rows(x: np.ndarray) -> np.ndarray:  # each template's query row, or (1, R, G * G)
            return x[row] if pairs else x[None]

        masks = [m for x in query if (m := x.mask) is not None]  # all or none: one model, one query
        query_mask = rows(cell_weights(np.stack(masks), self.grid)) if masks else None
        # as float32: a float16 sum of a silhouette's cells is rounded where it needs more than 11 bits
        sil = templates(_f32(stored.silhouettes))
        score = masked_distance(cos, sil, query_mask, c.coverage)
        reliefs = [x.relief for x in query]
        if not c.relief or stored.relief is None or any(x is None for x in reliefs):
            return score
        values, shares = (np.stack(v) for v in zip(*reliefs, strict=True))  # none is None here
        clip = c.relief_clip_mm / self.window_mm
        return score + c.relief * relief_distance(
            rows(values), rows(shares), templates(_f32(stored.relief)), sil, clip
        )


def _f32(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, np.float32)
