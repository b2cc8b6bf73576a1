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
