"""Photometric augmentation of training patches."""

from __future__ import annotations

import cv2
import numpy as np


def colour_jitter(rgb: np.ndarray, rng: np.random.Generator, strength: float) -> np.ndarray:
    """Random gamma, saturation, contrast and a small hue turn: a mesh's colours, baked under the scanner's
    light, never match what a camera makes of the object. Shape: (S, S, 3) uint8 -> same."""
    if strength <= 0:
        return rgb
    s = strength
    x = (rgb.astype(np.float32) / 255.0) ** rng.uniform(1 - 0.35 * s, 1 + 0.5 * s)
    grey = x.mean(axis=2, keepdims=True)
    x = grey + (x - grey) * rng.uniform(1 - 0.4 * s, 1 + 0.4 * s)
    x = x.mean() + (x - x.mean()) * rng.uniform(1 - 0.25 * s, 1 + 0.25 * s)
    out = np.clip(x * 255.0, 0, 255).astype(np.uint8)
    hsv = cv2.cvtColor(out, cv2.COLOR_RGB2HSV)  # OpenCV's hue is 0-179 (2 degrees a step)
    hsv[..., 0] = ((hsv[..., 0].astype(np.int16) + int(round(rng.uniform(-4, 4) * s))) % 180).astype(np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)


def soft_edges(
    rgb: np.ndarray, background: np.ndarray, mask: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """`rgb` where `mask` is, `background` elsewhere, blended across the outline over a Gaussian of 0.4-1.2
    px, each colour channel's blend shifted by up to 0.75 px: a camera's optics, demosaicing and
    compression smear an object's edge into what is behind it, where a render's edge is a hard step.
    Shape: (S, S, 3) uint8 twice, (S, S) bool -> (S, S, 3) float32."""
    alpha = cv2.GaussianBlur(mask.astype(np.float32), (0, 0), rng.uniform(0.4, 1.2))
    out = np.empty(rgb.shape, np.float32)
    for c in range(3):
        dx, dy = rng.uniform(-0.75, 0.75, 2)
        shift: np.ndarray = np.float32([[1, 0, dx], [0, 1, dy]])  # type: ignore[arg-type, assignment]  # numpy's stub
        a = cv2.warpAffine(
            alpha, shift, alpha.shape[::-1], flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        )
        out[..., c] = a * rgb[..., c] + (1 - a) * background[..., c]
    return out
