"""Our descriptor, for both protocol families:
- the service protocol asks the service itself (`service.recognition.recognise`, see `evaluation.served`):
  `answers` turns its distinct answers into arrays;
- the paper and full protocols: `rank` embeds the templates with the service's own
  `index.templates.register.embed_templates` and the test patches with the same embedder (sensor holes filled), and
  finds the exact nearest templates in Euclidean distance: the paper's nearest neighbour by descriptor,
  so the templates' local features (the service's re-ranking) are not made."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from evaluation.paper.neighbours import Ranking, knn, separation
from index.store import Match
from index.templates.register import embed_templates

if TYPE_CHECKING:
    from evaluation.paper.samples import Samples
    from evaluation.paper.templates import RenderedTemplates
    from index.features.embed import Embedder


def embed(
    embedder: Embedder,
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    nominal_mm: float | np.ndarray,
    fill: bool,
    batch: int = 2048,
    progress: Callable[[int], object] | None = None,
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


def rank(
    embedder: Embedder,
    templates: RenderedTemplates,
    samples: Samples,
    n: int,
    progress: Callable[[int], object] | None = None,
) -> Ranking:
    """The n nearest templates of every test patch by our descriptor."""
    t, s = templates, samples
    t_desc = np.zeros((len(t), embedder.dim), np.float32)
    for obj in np.unique(t.obj_ids):
        idx = t.of(int(obj))
        rendered = {t.window_mm: t.object_templates(int(obj))}
        t_desc[idx] = embed_templates(embedder, rendered, local_features=False).descriptors
        if progress:
            progress(len(idx))
    s_desc = embed(embedder, s.rgb, s.depth, s.distances, True)
    neighbours, scores = knn(s_desc, t_desc, n)

    def lookup(i: int, idx: np.ndarray) -> np.ndarray:
        return np.linalg.norm(t_desc[idx] - s_desc[i], axis=1)

    return Ranking(
        neighbours,
        scores,
        separation(s_desc, t_desc, t.obj_ids, s.obj_ids, "l2"),
        lookup,
        {"templates": t_desc, "samples": s_desc},
    )


def answers(matches: Sequence[Match], dataset_ids: dict[int, int], k: int) -> tuple[np.ndarray, ...]:
    """The service's answers to one query as arrays: (object (k,), the dataset's id, -1 = none; views
    (k, 3) azimuth, elevation, in-plane; distances (k,), nan = none)."""
    obj, views, dist = np.full(k, -1, int), np.zeros((k, 3)), np.full(k, np.nan)
    for j, m in enumerate(matches[:k]):
        obj[j] = dataset_ids.get(m.object_id, -1)
        views[j] = m.azimuth, m.elevation, m.inplane
        dist[j] = m.distance
    return obj, views, dist
