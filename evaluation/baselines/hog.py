"""HOG baseline: OpenCV `HOGDescriptor` with a 64x64 window, 8x8 cells, 16x16 blocks, stride 8 and 9
bins: 1764 values per channel; the channels of the modality (R, G, B and/or depth) are described one by
one and stacked, the whole L2-normalised; similarity is the dot product.

Each channel is the network's own input (index/features/patches.py) mapped to 8 bits, so HOG sees exactly the
patches our descriptor sees: the same crop, the same depth hole filling and depth normalisation.
`rank` is the method's adapter: the exact nearest templates by dot product (`faiss.knn`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import cv2
import numpy as np

from evaluation.paper.neighbours import Ranking, knn, separation
from index.features.patches import batch_inputs

if TYPE_CHECKING:
    from evaluation.paper.samples import Samples
    from evaluation.paper.templates import RenderedTemplates
    from index.features.embed import Embedder


HOG_DIM_PER_CHANNEL = 1764


def hog_descriptor() -> cv2.HOGDescriptor:
    return cv2.HOGDescriptor((64, 64), (16, 16), (8, 8), (8, 8), 9)


def _to_u8(x: np.ndarray) -> np.ndarray:
    """A normalised input channel (rgb ~ zero mean unit variance; depth in [-1, 1]) -> uint8."""
    return np.clip(x * 64.0 + 128.0, 0, 255).astype(np.uint8)


def describe_inputs(x: np.ndarray, hog: cv2.HOGDescriptor | None = None) -> np.ndarray:
    """Network inputs (N, C, 64, 64) -> (N, 1764 x C) float16, unit L2: HOG of every channel, stacked."""
    hog = hog if hog is not None else hog_descriptor()
    out = np.zeros((len(x), HOG_DIM_PER_CHANNEL * x.shape[1]), np.float16)
    for i, patch in enumerate(x):
        d = np.concatenate([np.asarray(hog.compute(_to_u8(ch))).ravel() for ch in patch])
        out[i] = d / max(float(np.linalg.norm(d)), 1e-12)
    return out


def hog_descriptors(
    modality: str,
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    nominal_mm: float | np.ndarray,
    window_mm: float,
    fill: bool,
    batch: int = 1024,
    progress: Callable[[int], object] | None = None,
) -> np.ndarray:
    """Patches (rgb (N, 64, 64, 3) uint8, depth (N, 64, 64) mm) -> (N, 1764 x channels) float16, unit L2.

    float16: the full protocol has tens of thousands of templates of 5,000+ values each."""
    hog = hog_descriptor()
    n = len(rgb if rgb is not None else depth)  # type: ignore[arg-type]
    nominal = np.broadcast_to(np.asarray(nominal_mm, dtype=float), (n,))
    out = None
    for lo in range(0, n, batch):
        hi = min(n, lo + batch)
        x = batch_inputs(
            modality,
            None if rgb is None else rgb[lo:hi],
            None if depth is None else depth[lo:hi],
            nominal[lo:hi],
            window_mm,
            fill,
        )
        if out is None:
            out = np.zeros((n, HOG_DIM_PER_CHANNEL * x.shape[1]), np.float16)
        out[lo:hi] = describe_inputs(x, hog)
        if progress:
            progress(hi - lo)
    return out if out is not None else np.zeros((0, HOG_DIM_PER_CHANNEL), np.float16)


def rank(
    embedder: Embedder,
    templates: RenderedTemplates,
    samples: Samples,
    n: int,
    progress: Callable[[int], object] | None = None,
) -> Ranking:
    """The n nearest templates of every test patch by HOG (on the inputs `embedder`'s model takes)."""
    t, s, m, w = templates, samples, embedder.modality, embedder.info.window_mm
    t_nominal = np.array([v.distance for v in t.views])
    t_desc = hog_descriptors(m, t.rgb, t.depth, t_nominal, w, False, progress=progress)
    s_desc = hog_descriptors(m, s.rgb, s.depth, s.distances, w, True)
    neighbours, scores = knn(s_desc, t_desc, n, "dot")

    def lookup(i: int, idx: np.ndarray) -> np.ndarray:
        dot = t_desc[idx].astype(np.float32) @ s_desc[i].astype(np.float32)
        return np.sqrt(np.maximum(2.0 - 2.0 * dot, 0.0))

    return Ranking(neighbours, scores, separation(s_desc, t_desc, t.obj_ids, s.obj_ids, "dot"), lookup)
