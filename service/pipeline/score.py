"""The re-ranking's score, one implementation for every stage that scores a pose (`rerank`, `sweep`,
`refine`): a stored template's local features (`index.features.embed.LOCAL_NAME`, the pretrained trunk's map)
against the query's, cut upright at the pose's roll, cell by cell where the object is
(`index.features.local.masked_distance`: the template's silhouette, and the query's mask when the model has one),
plus with depth the distance of their reliefs (`index.features.local.relief_distance`, weighed by
`relief_weight`). Templates stored without silhouettes (older stores) are compared as whole maps (`l2`).

Two shapes of one score: `pairs` (each template at its own roll) and `table` (every template at every one
of some rolls). They share every step but the cells' cosines, where each has its kernel: pairs one product
per roll over that roll's templates, the table one small matrix product per cell
(`index.features.local.cell_dots_across`, so a template read once serves every roll). The same table as two large
matrix products over all templates and rolls (each template weighed by its silhouette first) was 3-5x
slower than the per-cell products here (150 templates x 12 rolls, numpy, busy machine).

One `LocalScore` serves a query's three stages: a template is read from the store and made float32 once
(the first stage reads 400, the sweep's and the refinement's are mostly among them), and every pose is
scored once (a pose asked for again, by a later stage or a second candidate, is looked up). Before, each
stage read and converted its templates again and the stages kept the scores in a dictionary of poses:
with the search's answers made into objects one by one, those were a third of a query at 100 objects
(docs/experiments.md, "Speed" of issue 28)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from index.features.local import (
    StoredLocal,
    as_float32,
    cell_dots_across,
    cell_shares,
    cell_weights,
    l2,
    leading_float32,
    relief,
    relief_distance,
    uncovered,
    unit_cells,
)
from index.features.patches import batch_inputs, turn_masks
from service.pipeline.context import Key, Pose
from service.pipeline.mask import filled, foreground, masked
from service.pipeline.query import Decoded, Query, cut
from service.settings import Settings

# The score's constants (`ScoreConfig`), as the validation frames chose them; an experiment sets them in its
# own process before the pipelines are built.
#: `index.features.local.masked_distance`'s weight of the query's mask left outside a template's silhouette.
#: 0.3: chosen on the validation frames among 0, 0.15, 0.3, 0.5, 0.6, 1 (docs/experiments.md: 0 / 0.3 / 0.6
#: 64.3 / 69.6 / 68.7 % within 20 deg; at five camera rolls 0.15 +0.4 and 0.5 -0.9 against 0.3, both within
#: the noise)
MASK_COVERAGE = 0.3
#: a cell's residual depth counts up to this in the relief distance (mm), so an occluder's cell or a depth
#: hole costs at most that. 20: chosen with the weight (`Settings.relief_weight`) on the validation frames
#: (docs/experiments.md; 10 mm tied), kept wide for real depth: a real Kinect frame differs from its render by
#: a median absolute 4.2 mm on object pixels (docs/templates.md)
RELIEF_CLIP_MM = 20.0


@dataclass(frozen=True)
class ScoreConfig:
    """`coverage`: `index.features.local.masked_distance`'s weight of the query's mask left outside a template's
    silhouette (`MASK_COVERAGE`). `relief`: the weight of `index.features.local.relief_distance` added where
    both have depth (`Settings.relief_weight`), its residuals clipped at `relief_clip_mm` (`RELIEF_CLIP_MM`)."""

    coverage: float
    relief: float
    relief_clip_mm: float

    @classmethod
    def from_settings(cls, settings: Settings) -> ScoreConfig:
        return cls(MASK_COVERAGE, settings.relief_weight, RELIEF_CLIP_MM)


@dataclass(frozen=True)
class RollCut:
    """The query cut upright at one roll, as the score compares it: the local features (F,), its mask
    (S, S) bool or None, and its relief (`index.features.local.relief`: values and shares, (G * G,) each) or None
    without depth."""

    features: np.ndarray
    mask: np.ndarray | None
    relief: tuple[np.ndarray, np.ndarray] | None


class QueryCuts:
    """The query's cuts by roll, each made once for the whole query: every stage asks again for rolls an
    earlier one cut. `mask`: (in-plane, mask (S, S)) of the query cut at that in-plane, as the mask stage
    found it: turned to each roll (`turn_masks`) rather than found again, which would run the mask head
    once a roll. `patch_distance_mm`: as `service.pipeline.query.cut` takes it; `window_mm`: the window
    the query is cut through (its objects' class, `index.templates.windows`; None: the model's)."""

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
        q = replace(q, depth_scale=d.depth_scale)
        far = (
            self._patch_mm * window / d.embedder.info.window_mm
        )  # as `Cut`: a patch's, scaled with its window
        p = cut(q, d.rgb, d.depth, spec, rolls, patch_distance_mm=far)
        keep = None
        if mask is not None:
            keep = np.stack([turn_masks(mask[1][None], r - mask[0], spec)[0] for r in rolls])
            p = masked(filled(p, keep), keep)
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


class LocalScore:
    """The score of stored templates (`local`: the snapshot's local features by viewpoint) against this
    query's cuts (`cuts`), as `config` says, every pose scored once for the whole query: a later stage
    asking again for a pose an earlier one scored gets the number back, not a second computation.
    `window_mm`: the model's; the relief's clip is `relief_clip_mm` / `window_mm` windows whatever window
    the query is cut through: `relief_clip_mm` is the clip at the model's window, and scales with an
    object's (`index.templates.windows`).

    Each template is read and prepared once per query, when a stage first scores it (`_Prepared`): its
    values as float32 with one over each cell's length, its silhouette's weights as shares
    (`index.features.local.cell_shares`); each cut of the query with its cells made unit vectors
    (`index.features.local.unit_cells`) and its mask's weights as shares. The cells' cosines are then dot products
    times those lengths, and `masked_distance` weighted sums of them: the same formula (tested against
    it: `tests/index/features/test_local.py`). Templates stored without silhouettes (older stores) are compared as
    whole maps (`l2`)."""

    def __init__(
        self,
        config: ScoreConfig,
        cuts: QueryCuts,
        local: Mapping[Key, np.ndarray],
        grid: int,
        window_mm: float,
    ):
        self.config, self.cuts, self.local, self.grid, self.window_mm = config, cuts, local, grid, window_mm
        self._rows: dict[Key, int] = {}  # prepared templates: their row in `_t`
        self._cols: dict[float, int] = {}  # prepared cuts of the query: their row in `_q`
        self._t, self._q = _Prepared(), _Prepared()
        self._memo = np.full((0, 0), np.nan, np.float32)  # (rows, columns): NaN where not scored yet
        #: poses computed (not found in the memo): what a test of "each pose once" counts
        self.computed = 0

    def pairs(self, poses: Sequence[Pose]) -> np.ndarray:
        """Each pose's score: its viewpoint's template against the query cut at its roll. Shape: (N,)."""
        if not poses:
            return np.zeros(0, np.float32)
        cols = self._prepare_cols([r for _, r in poses])
        # templates new to the query prepared in the order of their rolls: each roll's templates side by
        # side, compared with its cut without a copy
        order = np.argsort(cols, kind="stable")
        self._prepare_rows([poses[i][0] for i in order])
        rows = np.array([self._rows[k] for k, _ in poses], np.intp)
        todo = np.isnan(self._memo[rows, cols])
        if todo.any():  # each pose once, however often asked
            _, first = np.unique(rows[todo] * len(self._cols) + cols[todo], return_index=True)
            r, c = rows[todo][np.sort(first)], cols[todo][np.sort(first)]
            self._memo[r, c] = self._distance(r, c, pairs=True)
            self.computed += len(r)
        return self._memo[rows, cols]

    def table(self, keys: Sequence[Key], rolls: Sequence[float]) -> np.ndarray:
        """Every viewpoint's template (`keys`) against the query cut at every one of `rolls`, each
        template read once. Shape: (N, R)."""
        cols = self._prepare_cols(rolls)
        rows = self._prepare_rows(keys)
        known = self._memo[np.ix_(rows, cols)]
        if (todo := np.isnan(known)).any():
            self.computed += int(todo.sum())
            known = np.where(todo, self._distance(rows, cols), known)  # a pose scored already keeps its score
            self._memo[np.ix_(rows, cols)] = known
        return known

    def _distance(self, rows: np.ndarray, cols: np.ndarray, pairs: bool = False) -> np.ndarray:
        """Scores of the prepared templates `rows` (n,) against the prepared cuts `cols`: every one of them
        (r,) -> (n, r), or with `pairs` each template against its own (n,) -> (n,); from their cells'
        cosines as `index.features.local.masked_distance`, plus the relief's distance."""
        t, q, c = self._t, self._q, self.config
        if t.shares is None or t.inverse is None:  # no silhouettes stored: whole maps
            diff = t.raw[rows][:, None, :] - q.raw[cols][None]
            return (
                np.sqrt(np.einsum("nrf,nrf->nr", diff, diff)) if not pairs else l2(q.raw[cols], t.raw[rows])
            )
        if pairs:  # one product per roll: its templates (side by side when prepared so) against its cut
            cos = np.empty((len(rows), 1, t.inverse.shape[1]), np.float32)
            for col in np.unique(cols):
                at = np.flatnonzero(cols == col)
                cos[at, 0] = np.einsum("ncg,cg->ng", t.cells(_rows_of(rows[at])), q.cells(col))
            by_cut = cols[:, None]  # (n, 1): each template's cut
        else:
            cos = cell_dots_across(t.cells(_rows_of(rows)), q.cells(cols))
            by_cut = cols[None]  # (1, r): every cut
        cos *= t.inverse[rows][:, None, :]  # the cosines: the query's cells are unit vectors already
        score = 1.0 - _weighed(cos, t.shares[rows][:, None])  # over the template's silhouette
        if q.shares is not None:  # and over the query's mask, averaged, plus what the silhouette leaves out
            assert q.weights is not None and t.weights is not None
            score = 0.5 * (score + 1.0 - _weighed(cos, q.shares[by_cut]))
            if c.coverage:
                score = score + c.coverage * uncovered(q.weights[by_cut], t.weights[rows][:, None])
        if c.relief and t.relief is not None and q.relief is not None and q.relief_shares is not None:
            assert t.weights is not None
            far = relief_distance(
                q.relief[by_cut],
                q.relief_shares[by_cut],
                t.relief[rows][:, None],
                t.weights[rows][:, None],
                c.relief_clip_mm / self.window_mm,
            )
            score = score + c.relief * far
        return score[:, 0] if pairs else score

    def _prepare_cols(self, rolls: Sequence[float]) -> np.ndarray:
        """The prepared cuts of the query at `rolls`, those not cut yet made in one batch (`QueryCuts.at`)."""
        if new := [r for r in dict.fromkeys(rolls) if r not in self._cols]:
            cut = self.cuts.at(new)
            masks = [m for x in cut if (m := x.mask) is not None]  # all or none: one model, one query
            reliefs = [x.relief for x in cut]
            values = shares = None
            if all(x is not None for x in reliefs):
                values, shares = (np.stack(v) for v in zip(*reliefs, strict=True))
            weights = cell_weights(np.stack(masks), self.grid) if masks else None
            feats = np.stack([x.features for x in cut])
            self._q.add(feats, weights, values, shares, self.grid, query=True)
            self._cols |= {r: len(self._cols) + i for i, r in enumerate(new)}
            self._grow()
        return np.array([self._cols[r] for r in rolls], np.intp)

    def _prepare_rows(self, keys: Sequence[Key]) -> np.ndarray:
        """The prepared templates of `keys`, those not prepared yet read in one batch."""
        if new := [k for k in dict.fromkeys(keys) if k not in self._rows]:
            features = self._q.raw.shape[1]  # F (a cut is made first): how `StoredLocal.of` reads a row
            rows = np.stack([np.asarray(self.local[k]) for k in new])
            stored = StoredLocal.of(rows, features, self.grid)
            self._t.add(rows, stored.silhouettes, stored.relief, None, self.grid, query=False, width=features)
            self._rows |= {k: len(self._rows) + i for i, k in enumerate(new)}
            self._grow()
        return np.array([self._rows[k] for k in keys], np.intp)

    def _grow(self) -> None:
        """The memo made as large as the rows and columns prepared, what it knew kept."""
        shape = (len(self._rows), len(self._cols))
        if self._memo.shape != shape:
            memo = np.full(shape, np.nan, np.float32)
            memo[: self._memo.shape[0], : self._memo.shape[1]] = self._memo
            self._memo = memo


class _Prepared:
    """Templates or cuts of the query as `LocalScore` compares them, in arrays that grow (their capacity
    doubled: a later stage adds rows without copying all before them): `cells`, the features as float32
    (the query's cuts: each cell a unit vector, `unit_cells`), and for templates `inverse`, one over each
    cell's length, applied to the products (a pass over the templates' values fewer than making them
    unit); `weights`, a silhouette's (a mask's) cells and `shares`, those as shares (`cell_shares`);
    `relief` (and `relief_shares`, the query's) where there is one; `raw`, the query's features as
    float32 (F, and `l2` against templates without silhouettes)."""

    def __init__(self) -> None:
        self.n = 0
        self._arrays: dict[str, np.ndarray] = {}
        self._cells = 0

    def part(self, name: str) -> np.ndarray | None:
        x = self._arrays.get(name)
        return None if x is None else x[: self.n]

    @property
    def raw(self) -> np.ndarray:
        x = self.part("raw")
        assert x is not None  # the query's cuts always keep theirs
        return x

    @property
    def inverse(self) -> np.ndarray | None:
        return self.part("inverse")

    @property
    def weights(self) -> np.ndarray | None:
        return self.part("weights")

    @property
    def shares(self) -> np.ndarray | None:
        return self.part("shares")

    @property
    def relief(self) -> np.ndarray | None:
        return self.part("relief")

    @property
    def relief_shares(self) -> np.ndarray | None:
        return self.part("relief_shares")

    def cells(self, at: slice | np.ndarray | np.intp) -> np.ndarray:
        """The cells of rows `at`, (n, C, G * G) (a slice: a view; one row: (C, G * G))."""
        x = self._arrays["cells"][: self.n][at]
        return x.reshape(*x.shape[:-1], -1, self._cells)

    def add(
        self,
        features: np.ndarray,
        weights: np.ndarray | None,
        relief: np.ndarray | None,
        relief_shares: np.ndarray | None,
        grid: int,
        *,
        query: bool,
        width: int | None = None,
    ) -> None:
        """Rows of `features` (m, F; `width`: F of wider rows, whose first F values are the features, as a
        template's stored row) with their cells' `weights` (m, G * G) and relief where given: the query's
        cuts (`query`: unit cells and raw features kept) or templates (their cells and inverse lengths,
        where they have weights: silhouettes)."""
        m, self._cells = len(features), grid * grid
        width = features.shape[1] if width is None else width
        parts = {"weights": weights, "relief": relief, "relief_shares": relief_shares}
        raw = query or weights is None  # the query's; templates without silhouettes are compared whole
        parts |= {
            "shares": None if weights is None else cell_shares(weights),
            "raw": features[:, :width] if raw else None,
        }
        cells = query or weights is not None
        for name in ("cells", *parts):
            x = features if name == "cells" else parts[name]
            if x is None or (name == "cells" and not cells):
                continue
            if name == "cells" and not query:  # a template's stored row: its features are its first values
                into = self._room(name, m, (width,))
                if x.dtype == np.float16:
                    leading_float32(x, width, into)
                else:
                    as_float32(x[:, :width], into)
            elif name == "cells":
                unit_cells(x, grid, out=(into := self._room(name, m, x.shape[1:])))
            else:
                as_float32(x, into := self._room(name, m, x.shape[1:]))
            if name == "cells" and not query:
                t = into.reshape(m, -1, self._cells)
                inverse = self._room("inverse", m, (self._cells,))
                np.divide(1.0, np.sqrt(np.einsum("ncg,ncg->ng", t, t)) + 1e-12, out=inverse)
        self.n += m

    def _room(self, name: str, m: int, shape: tuple[int, ...]) -> np.ndarray:
        """Rows n to n + m of part `name`, grown when it holds fewer (a view to write into)."""
        have = self._arrays.get(name)
        if have is None or len(have) < self.n + m:
            grown = np.empty((max(2 * (self.n + m), 64), *shape), np.float32)
            if have is not None:
                grown[: self.n] = have[: self.n]
            self._arrays[name] = have = grown
        return have[self.n : self.n + m]


def _weighed(cos: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Cells' cosines (n, r, G * G) summed with their weights (broadcast to them). Shape: -> (n, r)."""
    return np.einsum("...g,...g->...", cos, weights)


def _rows_of(rows: np.ndarray) -> slice | np.ndarray:
    """`rows` as a slice when they are consecutive and in order (a view of the prepared rows, no copy)."""
    if len(rows) and rows[-1] - rows[0] + 1 == len(rows) and (len(rows) == 1 or (np.diff(rows) == 1).all()):
        return slice(int(rows[0]), int(rows[-1]) + 1)
    return rows


def _f32(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, np.float32)
