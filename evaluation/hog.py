"""HOG baseline: OpenCV `HOGDescriptor` with a 64x64 window, 8x8 cells, 16x16 blocks, stride 8 and 9
bins: 1764 values per channel; the channels of the modality (R, G, B and/or depth) are described one by
one and stacked, the whole L2-normalised; similarity is the dot product.

Each channel is the network's own input (index/patches.py) mapped to 8 bits, so HOG sees exactly the
patches our descriptor sees: the same crop, the same depth hole filling and depth normalisation."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from index.patches import batch_inputs

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
        d = np.concatenate([hog.compute(_to_u8(ch)).ravel() for ch in patch])
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
    progress: Callable[[int], None] | None = None,
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
