"""Our descriptor: template descriptors as the service registers them, test descriptors with the same
embedder, exact nearest neighbours in Euclidean distance."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from index.embed import Embedder


def embed(
    embedder: Embedder,
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    nominal_mm: float | np.ndarray,
    fill: bool,
    batch: int = 2048,
    progress: Callable[[int], None] | None = None,
) -> np.ndarray:
    """Descriptors (N, D) float32 of patches, in batches (network inputs of 76k templates would not fit)."""
    n = len(rgb if rgb is not None else depth)  # type: ignore[arg-type]
    nominal = np.broadcast_to(np.asarray(nominal_mm, dtype=float), (n,))
    out = np.zeros((n, embedder.dim), np.float32)
    for lo in range(0, n, batch):
        hi = min(n, lo + batch)
        out[lo:hi] = embedder.embed_patches(
            None if rgb is None else rgb[lo:hi],
            None if depth is None else depth[lo:hi],
            nominal[lo:hi],
            fill=fill,
        )
        if progress:
            progress(hi - lo)
    return out


def distances(queries: np.ndarray, templates: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Euclidean distances (N, T), float32."""
    t = templates.astype(np.float32)
    t2 = (t * t).sum(axis=1)
    out = np.zeros((len(queries), len(t)), np.float32)
    for lo in range(0, len(queries), chunk):
        q = queries[lo : lo + chunk].astype(np.float32)
        d2 = (q * q).sum(axis=1)[:, None] + t2[None] - 2.0 * q @ t.T
        out[lo : lo + chunk] = np.sqrt(np.maximum(d2, 0.0))
    return out


def nearest(dist: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k smallest of each row, sorted: (indices (N, k), values (N, k))."""
    k = min(k, dist.shape[1])
    part = np.argpartition(dist, k - 1, axis=1)[:, :k]
    vals = np.take_along_axis(dist, part, axis=1)
    order = np.argsort(vals, axis=1, kind="stable")
    return np.take_along_axis(part, order, axis=1), np.take_along_axis(vals, order, axis=1)
