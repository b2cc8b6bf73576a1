"""Exact nearest templates for the descriptor methods (ours: Euclidean; HOG: dot product of unit vectors),
with `faiss.knn` over slices of the templates (HOG's thousands of values per template do not fit in
float32 all at once), and the collapse of a method's ranking to distinct (object, viewpoint) answers."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import faiss
import numpy as np

from index.store.answers import distinct

METRICS = {"l2": faiss.METRIC_L2, "dot": faiss.METRIC_INNER_PRODUCT}


@dataclass
class Ranking:
    """A method's nearest templates of every test patch. neighbours (N, n) template indices, -1 = none;
    scores (N, n) its distances (LineMOD: 100 - similarity), nearest first; separation (N,) nearest
    other-object / nearest same-object distance (nan: undefined); `lookup(i, idx)`: patch i's distances
    to the templates idx (nan where the method has none)."""

    neighbours: np.ndarray
    scores: np.ndarray
    separation: np.ndarray
    lookup: Callable[[int, np.ndarray], np.ndarray]
    descriptors: dict[str, np.ndarray] = field(default_factory=dict)  # "templates" / "samples"
    notes: list[str] = field(default_factory=list)


def knn(
    queries: np.ndarray, templates: np.ndarray, k: int, metric: str = "l2", chunk: int = 8192
) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest templates of every query: (indices (N, k), -1 = none; distances (N, k)), nearest
    first. "l2": Euclidean distance; "dot": largest dot product first, as the distance sqrt(2 - 2 dot)
    (unit vectors)."""
    dot = metric == "dot"
    q = np.ascontiguousarray(queries, np.float32)
    k = min(k, len(templates))
    heap = faiss.ResultHeap(len(q), k, keep_max=dot)
    for lo in range(0, len(templates), chunk):
        part = np.ascontiguousarray(templates[lo : lo + chunk], np.float32)
        D, I = faiss.knn(q, part, min(k, len(part)), METRICS[metric])
        heap.add_result(D, np.where(I >= 0, I + lo, -1))
    heap.finalize()
    d = np.sqrt(np.maximum(2.0 - 2.0 * heap.D, 0.0)) if dot else np.sqrt(np.maximum(heap.D, 0.0))
    return heap.I, d


def nearest_per_object(
    queries: np.ndarray, templates: np.ndarray, template_obj: np.ndarray, metric: str = "l2"
) -> tuple[np.ndarray, np.ndarray]:
    """Each query's distance to the nearest template of every object: (objects (O,), distances (N, O))."""
    objects = np.unique(template_obj)
    out = np.zeros((len(queries), len(objects)), np.float32)
    for j, o in enumerate(objects):
        out[:, j] = knn(queries, templates[template_obj == o], 1, metric)[1][:, 0]
    return objects, out


def separation(
    queries: np.ndarray, templates: np.ndarray, template_obj: np.ndarray, sample_obj: np.ndarray, metric: str
) -> np.ndarray:
    """Per query: distance to the nearest template of another object over distance to the nearest
    template of its own object (> 1: the objects are told apart; nan: undefined)."""
    objects, d = nearest_per_object(queries, templates, template_obj, metric)
    own = objects[None, :] == np.asarray(sample_obj)[:, None]
    d_own = np.where(own, d, np.inf).min(axis=1)
    d_other = np.where(~own, d, np.inf).min(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = d_other / d_own
    return np.where(np.isfinite(ratio), ratio, np.nan)


def distinct_rows(
    neighbours: np.ndarray, scores: np.ndarray, template_keys: tuple[np.ndarray, ...], k: int
) -> tuple[np.ndarray, np.ndarray]:
    """Each row's ranking (template indices (N, M), -1 = none; scores (N, M), smaller is better) collapsed
    to its k best distinct answers by the templates' keys (e.g. object, azimuth, elevation):
    (indices (N, k), -1 = none; scores (N, k), nan = none)."""
    out_i = np.full((len(neighbours), k), -1, int)
    out_s = np.full((len(neighbours), k), np.nan)
    for r, (row, sc) in enumerate(zip(neighbours, scores, strict=True)):
        ok = row >= 0
        row, sc = row[ok], sc[ok]
        best = distinct([key[row] for key in template_keys], sc, k)
        out_i[r, : len(best)], out_s[r, : len(best)] = row[best], sc[best]
    return out_i, out_s
