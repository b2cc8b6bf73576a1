"""Distinct answers: a query's k answers are k different (object, viewpoint) pairs, each at its best.

The in-plane variants of one viewpoint (and the turns of a query) are one answer, not k copies of the
nearest view, so the k answers of `/recognize` and of the evaluation are k poses to choose from. Used by
the store's search and, on the same templates, by the evaluation's baselines."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def distinct(keys: Sequence[np.ndarray], scores: np.ndarray, k: int) -> np.ndarray:
    """Indices of the k best distinct candidates, best (smallest score) first: of the candidates that
    share every key (e.g. object, azimuth, elevation) only the best counts.
    Shape: keys, each (M,); scores (M,) -> (<= k,) indices into the M candidates."""
    scores = np.asarray(scores)
    if len(scores) == 0 or k <= 0:
        return np.zeros(0, int)
    keys = [np.asarray(a) for a in keys]
    order = np.lexsort((scores, *reversed(keys)))  # by the keys, then the score: a group's best first
    new = np.zeros(len(order), bool)
    new[0] = True
    for a in keys:
        a = a[order]
        new[1:] |= a[1:] != a[:-1]
    best = order[new]
    return best[np.argsort(scores[best], kind="stable")][:k]
