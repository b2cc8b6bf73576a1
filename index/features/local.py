"""Local similarity between a query and a template, cell by cell, where the query's object is.

A model's `local` output (`index.features.embed.LOCAL_NAME`) is its pretrained trunk's map, channels first and
flattened: C channels on a G x G grid of cells. Two ways to compare a query with a template:

- `l2`: the whole maps, unit length, as vectors. Every cell counts, the clutter around the object too.
- `masked_cosine`: 1 - the cosine of each cell's C values (`cell_cosines`), averaged over the cells
  with weights: the share of each cell the object covers, in the template (its silhouette, stored beside
  its features at registration: `with_silhouettes`) and, for a model with a mask (`index.features.embed.MASK_NAME`:
  a head on the trunk, or an RGB-D model's depth), in the query. Clutter drops out of the score.
  Measured on validation frames (docs/experiments.md): within 20 deg 32 -> 44 %, right object 56 -> 76 %,
  against `l2` on the same candidates.

With depth, the shape too: `relief` is each cell's mean depth from the patch's distance, stored for every
template after its silhouette (`with_relief`) and taken from an RGB-D query's depth inside its mask;
`relief_distance` compares the two up to their offset. Measured on validation frames (docs/experiments.md):
the RGB-D model within 20 deg 76.6 -> 91.4 %.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np
import onnxruntime as ort


def cell_cosines(
    query: np.ndarray, templates: np.ndarray, grid: int, rows: np.ndarray | None = None
) -> np.ndarray:
    """Cosine between a query's and each template's values in each cell (a zero cell: 0): template j
    against query `rows[j]` (default j; templates sorted by their row are compared without copies).
    Shape: (Q, C * G * G), (N, C * G * G) channels first, rows (N,) -> (N, G * G)."""
    n, g2 = len(templates), grid * grid
    q = as_float32(query).reshape(len(query), -1, g2)
    q = q / (np.sqrt(np.einsum("qcg,qcg->qg", q, q))[:, None] + 1e-12)  # each query cell a unit vector
    rows = np.zeros(n, int) if rows is None and len(q) == 1 else rows
    t = as_float32(templates).reshape(n, -1, g2)
    norms = np.sqrt(np.einsum("ncg,ncg->ng", t, t)) + 1e-12
    if rows is None:
        return np.einsum("ncg,ncg->ng", q, t) / norms
    dots = np.empty((n, g2), np.float32)
    for r in np.unique(rows):  # each query row against its templates: no (N, C, G) copy of the query
        at = np.flatnonzero(rows == r)
        block = slice(at[0], at[-1] + 1) if at[-1] - at[0] + 1 == len(at) else at  # sorted rows: a view
        dots[block] = np.einsum("ncg,cg->ng", t[block], q[r])
    return dots / norms


def cell_cosines_across(query: np.ndarray, templates: np.ndarray, grid: int) -> np.ndarray:
    """`cell_cosines` of every template against every query row at once (`cell_dots_across` of their unit
    cells). Shape: (R, C * G * G), (N, C * G * G) channels first -> (N, R, G * G)."""
    g2 = grid * grid
    t, q = unit_cells(templates, grid), unit_cells(query, grid)
    return cell_dots_across(t.reshape(len(t), -1, g2), q.reshape(len(q), -1, g2))


def cell_dots_across(templates: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """Each cell's dot product of every template against every query row: one small matrix product per
    cell, (N, C) by (C, R), so a template read once serves every row (of unit cells, `unit_cells`: their
    cosines). The maps are turned cells-first by OpenCV's transpose: in a micro-benchmark here (150
    templates, 12 rolls, one thread) numpy's strided copies and the product took 6.1 ms, OpenCV's
    transposes and the product 0.8. Shape: (N, C, G * G), (R, C, G * G) float32 -> (N, R, G * G)."""
    (n, c, g2), r = templates.shape, len(queries)
    tg = _cells_first(templates.reshape(n * c, g2)).reshape(g2, n, c)
    qg = _cells_first(queries.reshape(r * c, g2)).reshape(g2, r, c)
    dots = np.matmul(tg, qg.transpose(0, 2, 1))  # (G * G, N, R)
    return _cells_first(dots.reshape(g2, n * r)).reshape(n, r, g2)


def _cells_first(x: np.ndarray) -> np.ndarray:
    """A 2-D float32 array transposed (OpenCV's), contiguous."""
    return np.asarray(cv2.transpose(np.ascontiguousarray(x, np.float32)))


def as_float32(x: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """As float32 (into `out` when given, a C-contiguous array of x's shape). float16 (how local features
    are stored) through OpenCV's vectorised conversion: numpy's took 2 ms for the 200 candidates' maps of
    one query here, OpenCV's 0.6."""
    x = np.asarray(x)
    if x.dtype == np.float16 and x.ndim == 2 and x.size:
        # a scalar src2; `dst` of the right shape and type is written in place
        got = np.asarray(cv2.add(x, 0.0, dst=out, dtype=cv2.CV_32F))  # type: ignore[call-overload]
        if out is not None and not np.shares_memory(got, out):
            out[...] = got
        return out if out is not None else got
    if out is None:
        return np.asarray(x, np.float32)
    out[...] = x
    return out


def leading_float32(rows: np.ndarray, width: int, out: np.ndarray | None = None) -> np.ndarray:
    """The first `width` values of each of `rows` (N, W) float16 as float32 (N, width), into `out` when
    given (C-contiguous). Through onnxruntime's Cast (one intra-op thread), which writes into `out`
    itself: 400 stored templates' features (6,144 values each) 0.6-0.9 ms here against OpenCV's 1.8-2.1
    (`as_float32`), on a busy machine, one thread."""
    rows = np.ascontiguousarray(rows, np.float16)
    if out is None:
        out = np.empty((len(rows), width), np.float32)
    if not len(rows):
        return out
    binding = _cast_session().io_binding()
    binding.bind_cpu_input("rows", rows)
    binding.bind_cpu_input("width", np.array([width], np.int64))
    binding.bind_output("out", "cpu", 0, np.float32, [len(rows), width], out.ctypes.data)
    _cast_session().run_with_iobinding(binding)
    return out


@functools.cache
def _cast_session() -> ort.InferenceSession:
    """A session of one graph: rows (N, W) float16 -> their first `width` values as float32."""
    from onnx import TensorProto, helper

    nodes = [
        helper.make_node("Slice", ["rows", "zero", "width", "one"], ["cut"]),
        helper.make_node("Cast", ["cut"], ["out"], to=TensorProto.FLOAT),
    ]
    constants = [
        helper.make_tensor("zero", TensorProto.INT64, [1], [0]),
        helper.make_tensor("one", TensorProto.INT64, [1], [1]),
    ]
    graph = helper.make_graph(
        nodes,
        "leading_float32",
        [
            helper.make_tensor_value_info("rows", TensorProto.FLOAT16, [None, None]),
            helper.make_tensor_value_info("width", TensorProto.INT64, [1]),
        ],
        [helper.make_tensor_value_info("out", TensorProto.FLOAT, [None, None])],
        constants,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=9)
    opts = ort.SessionOptions()
    opts.intra_op_num_threads, opts.inter_op_num_threads = 1, 1
    return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])


def unit_cells(x: np.ndarray, grid: int, out: np.ndarray | None = None) -> np.ndarray:
    """Local maps with each cell's C values scaled to unit length (a zero cell stays zero), as float32,
    flattened channels first again (into `out` when given: (N, C * G * G) float32): the cosine of two
    cells is then their dot product (`cell_dots_across`). Shape: (N, C * G * G) -> (N, C * G * G)."""
    n, g2 = len(x), grid * grid
    if out is None:
        out = np.empty((n, np.shape(x)[1]), np.float32)
    t = as_float32(x, out).reshape(n, -1, g2)
    norms = np.sqrt(np.einsum("ncg,ncg->ng", t, t)) + 1e-12
    np.divide(t, norms[:, None, :], out=t)
    return out


def cell_shares(weights: np.ndarray) -> np.ndarray:
    """Cells' weights (`cell_weights`, a silhouette's or a mask's) as shares that sum to 1, every cell alike
    where they are all zero: `masked_cosine` is 1 - the cosines weighed by these. Shape: (N, G * G) ->
    (N, G * G) float32."""
    w = np.asarray(weights, np.float32)
    total = w.sum(axis=-1, keepdims=True)
    return np.where(total > 0, w / np.maximum(total, 1e-12), np.float32(1.0 / w.shape[-1])).astype(np.float32)


def cell_weights(mask: np.ndarray, grid: int) -> np.ndarray:
    """Masks -> the share of each cell they cover. Shape: (N, S, S) bool -> (N, G * G), S = G * k."""
    n, s = mask.shape[0], mask.shape[1]
    k = s // grid
    return mask.reshape(n, grid, k, grid, k).mean(axis=(2, 4)).reshape(n, grid * grid).astype(np.float32)


def masked_cosine(cosines: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Distance in [0, 2]: 1 - cosine per cell (`cell_cosines`) averaged with the cells' weights; a query
    whose weights are all zero (an empty mask) weighs every cell alike. Shape: (..., G * G) and weights
    that broadcast to it -> (...): pairs (N, G * G) x 2 -> (N,), or every template against every query
    row (`cell_cosines_across`, (N, R, G * G)) with weights (N, 1, G * G) or (1, R, G * G) -> (N, R)."""
    total = weights.sum(axis=-1)
    # sum((1 - c) w) / sum(w) = 1 - (c . w) / sum(w): one product per row, no (N, G * G) temporaries
    dots = np.einsum("...g,...g->...", cosines, weights)
    if (empty := total <= 0).any():
        dots, total = np.where(empty, cosines.sum(axis=-1), dots), np.where(empty, cosines.shape[-1], total)
    return 1.0 - dots / total


def masked_distance(
    cosines: np.ndarray, silhouettes: np.ndarray, query_mask: np.ndarray | None = None, coverage: float = 0.0
) -> np.ndarray:
    """The re-ranking's score: `masked_cosine` over the template's silhouette, averaged with the same
    over the query's mask when there is one (where the template's object is, the query must look like
    it; where the query's object is, the template must); plus `coverage` times the share of the query's
    mask the template's silhouette leaves uncovered (`uncovered`: the object seen must lie inside the
    template's outline, whatever hides part of it). Shapes as `masked_cosine`'s: (N, G * G) x 2 or 3
    -> (N,), or (N, R, G * G), (N, 1, G * G), (1, R, G * G) -> (N, R)."""
    score = masked_cosine(cosines, silhouettes)
    if query_mask is None:
        return score
    score = 0.5 * (score + masked_cosine(cosines, query_mask))
    return score + coverage * uncovered(query_mask, silhouettes) if coverage else score


def uncovered(query_mask: np.ndarray, silhouettes: np.ndarray) -> np.ndarray:
    """The share of the query's mask outside the template's silhouette, in [0, 1] (cells' shares of
    both, `cell_weights`; an empty query mask: 0). Shape: (..., G * G) x 2, broadcast -> (...)."""
    area = query_mask.sum(axis=-1)
    inside = (query_mask * silhouettes).sum(axis=-1)
    return np.where(area > 0, 1.0 - inside / np.maximum(area, 1e-12), 0.0)


def with_silhouettes(local: np.ndarray, depth: np.ndarray, grid: int) -> np.ndarray:
    """Templates' local features with their silhouettes' cell weights appended (renders: the object is
    where depth is), as a model with a mask head stores them. Shape: (N, F), (N, S, S) -> (N, F + G * G)."""
    return np.concatenate([np.asarray(local, np.float32), cell_weights(depth > 0, grid)], axis=1)


def with_relief(
    stored: np.ndarray, depth: np.ndarray, distance: np.ndarray, grid: int, window_mm: float
) -> np.ndarray:
    """`with_silhouettes`' rows with each template's relief appended (`relief`: its cells' depth relative
    to the render distance), as registration stores them for every model with local features (the RGB-D
    model takes the rgb model's templates).
    Shape: (N, F + G * G), (N, S, S) mm, (N,) mm -> (N, F + 2 * G * G)."""
    values, _ = relief(depth, distance, grid, window_mm)
    return np.concatenate([np.asarray(stored, np.float32), values], axis=1)


@dataclass(frozen=True)
class StoredLocal:
    """Stored local rows in their parts: `features` (N, F), the silhouettes' cell weights
    (`with_silhouettes`, (N, G * G)) and the relief (`with_relief`, (N, G * G)) where stored, else None.

    Which parts a row holds is read from its width (`of`), the only place it is written: registration
    stores all three (`with_relief`), but rows registered before silhouettes (F values) or before the
    relief (F + G * G) stay valid in the stores kept from then, and a store records no layout beside
    them. F (the model's channels times G * G) and G come from the model, so the three widths differ."""

    features: np.ndarray
    silhouettes: np.ndarray | None
    relief: np.ndarray | None

    @classmethod
    def of(cls, stored: np.ndarray, features: int, grid: int) -> StoredLocal:
        """Rows (N, F [+ G * G [+ G * G]]) of `features` values each, then the parts their width says."""
        g2, width = grid * grid, stored.shape[1]
        if width not in (features, features + g2, features + 2 * g2):
            raise ValueError(
                f"stored local rows of {width} values fit neither {features} features nor their masks"
            )
        parts = (width - features) // g2
        cells = [stored[:, features + i * g2 : features + (i + 1) * g2] for i in range(parts)]
        silhouettes, relief = (cells + [None, None])[:2]
        return cls(stored[:, :features], silhouettes, relief)


def relief(
    depth: np.ndarray, distance: np.ndarray, grid: int, window_mm: float, keep: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's mean depth relative to `distance`, in windows (`window_mm`), over its pixels with depth
    (and inside `keep`), and the share of its pixels that have one (0 where none). The object's shape as
    depth sees it: for RGB-D queries the re-ranking compares it with the template's (`relief_distance`).
    Shape: (N, S, S) mm, (N,) mm, keep (N, S, S) bool -> (N, G * G) x 2."""
    depth = np.asarray(depth, np.float32)
    n, s = depth.shape[:2]
    k = s // grid
    valid = depth > 0 if keep is None else (depth > 0) & keep
    near = np.asarray(distance, np.float32).reshape(-1, 1, 1)
    rel = np.where(valid, (depth - near) / window_mm, 0.0).astype(np.float32)
    # (n, G * G), not (n, -1): a chunk of views without an upright one has none (n = 0)
    sums = rel.reshape(n, grid, k, grid, k).sum(axis=(2, 4)).reshape(n, grid * grid)
    counts = valid.reshape(n, grid, k, grid, k).sum(axis=(2, 4)).reshape(n, grid * grid).astype(np.float32)
    return sums / np.maximum(counts, 1.0), counts / (k * k)


#: `relief_distance`: the fewest cells two reliefs must share to be compared
RELIEF_MIN_CELLS = 3


def relief_distance(
    query: np.ndarray, shares: np.ndarray, templates: np.ndarray, silhouettes: np.ndarray, clip: float
) -> np.ndarray:
    """How far a query's relief is from each template's (`relief`), over the cells both cover more than
    half: the root mean square of their difference once its mean (the two distances' offset: the query's is
    measured at the surface, the template's at the object's origin) is taken out, each cell's residual
    clipped to +- `clip` (windows) so that a cell of an occluder or a depth hole costs at most that. 0 where
    they share fewer than `RELIEF_MIN_CELLS` cells. Shape: query, shares against templates, silhouettes,
    (..., G * G) each, broadcast: pairs (N, G * G) -> (N,), or every template against every query row
    (1, R, G * G) against (N, 1, G * G) -> (N, R)."""
    both = (shares > 0.5) & (silhouettes > 0.5)
    n = both.sum(axis=-1)
    diff = np.where(both, query - templates, 0.0)
    offset = diff.sum(axis=-1) / np.maximum(n, 1)
    residual = np.where(both, np.clip(diff - offset[..., None], -clip, clip), 0.0)
    rms = np.sqrt((residual * residual).sum(axis=-1) / np.maximum(n, 1))
    return np.where(n >= RELIEF_MIN_CELLS, rms, 0.0).astype(np.float32)


def l2(query: np.ndarray, templates: np.ndarray) -> np.ndarray:
    """L2 distance between whole unit-length maps. Shape: (N, F), (N, F) -> (N,)."""
    diff = np.asarray(query, np.float32) - np.asarray(templates, np.float32)
    return np.sqrt(np.einsum("nf,nf->n", diff, diff))
