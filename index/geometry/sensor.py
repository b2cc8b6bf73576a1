"""A sensor model that makes clean renders look like real RGB-D frames (Kinect-like), for training data
and synthetic evaluation. Works on whole renders or patches: rgb (H, W, 3) uint8, depth (H, W) mm.

Depth noise follows Nguyen, Izadi & Lovell (3DIMPVT 2012): axial sigma = 1.2 mm + 1.9 mm * (z/m - 0.4)^2;
quantisation follows the Kinect's 1/8-pixel disparity steps (focal 580 px, baseline 75 mm)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import overload

import cv2
import numpy as np


def fractal_noise(
    shape: tuple[int, int], rng: np.random.Generator, octaves: int = 5, persistence: float = 0.55
) -> np.ndarray:
    """Smooth random field in [0, 1]: upsampled white noise summed over octaves. Shape: `shape`."""
    h, w = shape
    out = np.zeros(shape, np.float32)
    amp, total = 1.0, 0.0
    for o in range(octaves):
        cells = 2 ** (o + 1)
        small = rng.random((cells + 1, cells + 1)).astype(np.float32)
        out += amp * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= persistence
    out /= total
    return (out - out.min()) / (np.ptp(out) + 1e-6)


@dataclass(frozen=True)
class SensorModel:
    """Parameters of the simulated sensor; the defaults look like LineMOD's Kinect frames."""

    depth_noise: bool = True
    quantise: bool = True
    focal_px: float = 580.0  # Kinect depth camera, for disparity quantisation
    baseline_mm: float = 75.0
    edge_dropout: float = 0.02  # chance an edge pixel is lost; a real LM-O frame: 2.8% (sensor_vs_real.py)
    edge_step_mm: float = 20.0  # a depth discontinuity at least this high is an edge
    random_dropout: float = 0.0007  # seeds 3x3 holes: 0.6% lost, as a real frame off edges (sensor_vs_real)
    rgb_noise_std: tuple[float, float] = (1.0, 6.0)  # range of per-image Gaussian noise, grey levels
    gain: tuple[float, float] = (0.6, 1.4)  # range of global brightness change
    channel_gain: float = 0.12  # +- per-channel colour cast
    blur_prob: float = 0.3  # chance of a slight defocus blur

    # What is given comes back, what is None stays None.
    @overload
    def apply(
        self,
        rgb: np.ndarray,
        depth: np.ndarray,
        rng: np.random.Generator,
        background_rgb: np.ndarray | None = None,
        background_depth: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]: ...
    @overload
    def apply(
        self,
        rgb: np.ndarray,
        depth: None,
        rng: np.random.Generator,
        background_rgb: np.ndarray | None = None,
        background_depth: np.ndarray | None = None,
    ) -> tuple[np.ndarray, None]: ...
    @overload
    def apply(
        self,
        rgb: None,
        depth: np.ndarray,
        rng: np.random.Generator,
        background_rgb: np.ndarray | None = None,
        background_depth: np.ndarray | None = None,
    ) -> tuple[None, np.ndarray]: ...
    @overload
    def apply(
        self,
        rgb: np.ndarray | None,
        depth: np.ndarray | None,
        rng: np.random.Generator,
        background_rgb: np.ndarray | None = None,
        background_depth: np.ndarray | None = None,
    ) -> tuple[np.ndarray | None, np.ndarray | None]: ...
    def apply(
        self,
        rgb: np.ndarray | None,
        depth: np.ndarray | None,
        rng: np.random.Generator,
        background_rgb: np.ndarray | None = None,
        background_depth: np.ndarray | None = None,
    ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Composite over the background where the render is empty (depth 0), then corrupt it."""
        mask = None if depth is None else depth > 0
        if rgb is not None:
            rgb = rgb.astype(np.float32)
            if background_rgb is not None and mask is not None:
                rgb = np.where(mask[..., None], rgb, background_rgb.astype(np.float32))
            rgb = self._rgb(rgb, rng)
        if depth is not None:
            depth = depth.astype(np.float32)
            if background_depth is not None and mask is not None:
                depth = np.where(mask, depth, background_depth.astype(np.float32))
            depth = self._depth(depth, rng)
        return rgb, depth

    def _rgb(self, rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        rgb = rgb * rng.uniform(*self.gain) * (1 + rng.uniform(-self.channel_gain, self.channel_gain, 3))
        if rng.random() < self.blur_prob:
            rgb = cv2.GaussianBlur(rgb, (0, 0), rng.uniform(0.4, 1.0))
        rgb = rgb + rng.normal(0, rng.uniform(*self.rgb_noise_std), rgb.shape)
        return np.clip(rgb, 0, 255).astype(np.uint8)

    def _depth(self, depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        valid = depth > 0
        out = depth.copy()
        if self.depth_noise:
            sigma = 1.2 + 1.9 * (depth / 1000.0 - 0.4) ** 2
            out = out + rng.normal(0, 1, depth.shape).astype(np.float32) * sigma
        if self.quantise:
            c = self.focal_px * self.baseline_mm * 8  # z = c / disparity, disparity in 1/8 px
            disparity = np.round(c / np.maximum(out, 1.0))
            out = c / np.maximum(disparity, 1.0)
        # Structured light misses depth where surfaces break off: drop pixels at depth discontinuities.
        # The 4-neighbour Laplacian is 0 on any plane however slanted (a gradient threshold would punch
        # holes all over a steep table) and about the step's height next to one.
        jumps = np.abs(cv2.Laplacian(depth, cv2.CV_32F, ksize=1)) > self.edge_step_mm
        jumps[[0, -1], :] = jumps[:, [0, -1]] = False  # no neighbours beyond the border to compare
        edges = cv2.dilate(jumps.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        drop = edges & (rng.random(depth.shape) < self.edge_dropout)
        holes = rng.random(depth.shape) < self.random_dropout
        drop |= cv2.dilate(holes.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        out[drop | ~valid] = 0.0
        return out.astype(np.float32)


def random_background(
    shape: tuple[int, int],
    rng: np.random.Generator,
    object_distance_mm: float,
    images: Sequence[np.ndarray] = (),
) -> tuple[np.ndarray, np.ndarray]:
    """A background: rgb (H, W, 3) uint8 from fractal noise or a random crop of one of `images`
    (RGB uint8 of any size), and depth (H, W) mm: a slanted, bumpy surface behind the object."""
    h, w = shape
    if images and rng.random() < 0.6:
        img = images[int(rng.integers(len(images)))]
        scale = max(h / img.shape[0], w / img.shape[1]) * rng.uniform(1.0, 2.0)
        img = cv2.resize(
            img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
        )
        y, x = rng.integers(0, img.shape[0] - h + 1), rng.integers(0, img.shape[1] - w + 1)
        rgb = img[y : y + h, x : x + w].copy()
    else:
        colors = rng.uniform(0, 255, (2, 3))
        t = fractal_noise(shape, rng)[..., None]
        rgb = (colors[0] * t + colors[1] * (1 - t)).astype(np.uint8)
    offset = rng.uniform(60.0, 600.0)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    slope = rng.uniform(-1.0, 1.0, 2) * (offset / max(h, w))
    bumps = (fractal_noise(shape, rng, octaves=3) - 0.5) * rng.uniform(0, 80)
    depth = object_distance_mm + offset + slope[0] * (yy - h / 2) + slope[1] * (xx - w / 2) + bumps
    return rgb, np.maximum(depth, object_distance_mm + 20).astype(np.float32)


def plane_depth(K: np.ndarray, normal: np.ndarray, offset: float, shape: tuple[int, int]) -> np.ndarray:
    """Depth (mm along the optical axis) at every pixel of a camera with intrinsics K of the plane
    {X : normal . X = offset} (camera frame, mm); 0 where a pixel's ray misses it or meets it behind.
    Shape: (H, W) float32."""
    h, w = shape
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    rays = np.linalg.inv(np.asarray(K, float)) @ np.stack([u.ravel(), v.ravel(), np.ones(h * w)])
    denom = np.asarray(normal, float) @ rays  # rays have z = 1, so offset / denom is the depth
    with np.errstate(divide="ignore", invalid="ignore"):
        z = offset / denom
    z[~np.isfinite(z) | (z <= 0)] = 0.0
    return z.reshape(h, w).astype(np.float32)


def support_plane(R_m2c: np.ndarray, t_m2c: np.ndarray, z_min: float) -> tuple[np.ndarray, float]:
    """The plane an upright object stands on, its own xy plane at height `z_min` (mm), in camera
    coordinates as (normal, offset). The template viewpoints' half-sphere assumes objects stand so."""
    R = np.asarray(R_m2c, float)
    n = R[:, 2]
    return n, float(n @ (R @ np.array([0.0, 0.0, z_min]) + np.ravel(t_m2c)))


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Least-squares plane through points (N >= 3, camera frame, mm), its normal facing the camera:
    (normal, offset, largest distance of a point from it)."""
    p = np.asarray(points, float)
    c = p.mean(axis=0)
    n = np.linalg.svd(p - c)[2][2]
    if n @ c > 0:  # the camera (origin) on the normal's side: offset < 0
        n = -n
    return n, float(n @ c), float(np.abs((p - c) @ n).max())


@overload
def with_support(
    depth: np.ndarray, rgb: np.ndarray, plane: np.ndarray, texture: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def with_support(
    depth: np.ndarray, rgb: None, plane: np.ndarray, texture: np.ndarray | None
) -> tuple[np.ndarray, None]: ...
@overload
def with_support(
    depth: np.ndarray, rgb: np.ndarray | None, plane: np.ndarray, texture: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]: ...
def with_support(
    depth: np.ndarray, rgb: np.ndarray | None, plane: np.ndarray, texture: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """A background (depth, rgb) with a support plane's depth `plane` (0 = none) in front of it, the
    plane showing `texture` (same size as rgb)."""
    on = (plane > 0) & ((plane < depth) | (depth <= 0))
    depth = np.where(on, plane, depth).astype(np.float32)
    if rgb is not None and texture is not None:
        rgb = np.where(on[..., None], texture, rgb).astype(np.uint8)
    return depth, rgb
