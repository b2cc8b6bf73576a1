"""What the network sees: a metric window around the object, warped to 64x64, normalised.

One code path for templates, training, evaluation and the service:
- `crop` cuts the window out of a full frame with a virtual camera that looks along the ray through the
  object centre (so an object off the optical axis looks as a centred render does), optionally undoing
  a known in-plane angle (the paper's rectified protocol). Depth becomes depth along that virtual axis.
- `fill_depth` closes sensor holes (zeros) with an iterated 3x3 median over valid pixels, as the paper.
- `normalise` maps depth relative to the object surface at the centre, +-window/2 -> [-1, 1] (clipped;
  empty pixels are far, +1), and RGB to zero mean, unit variance per channel.

Shape conventions: rgb (H, W, 3) uint8 RGB order; depth (H, W) float mm, 0 = no depth;
a network input is (C, S, S) float32 with channels R, G, B, D as the modality has them.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from index.pose import align_rotation, roll_rotation

MODALITY_CHANNELS = {"rgb": 3, "depth": 1, "rgbd": 4}


@dataclass(frozen=True)
class PatchSpec:
    """The window: `window_mm` x `window_mm` at the object's distance, sampled at `size` x `size` px."""

    size: int = 64
    window_mm: float = 200.0


def patch_camera(spec: PatchSpec, distance_mm: float) -> np.ndarray:
    """Intrinsics of the virtual camera whose `size` px image spans the window at `distance_mm`."""
    f = spec.size * distance_mm / spec.window_mm
    c = (spec.size - 1) / 2
    return np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])


def _homography(
    K: np.ndarray, centre_uv: tuple[float, float], distance_mm: float, spec: PatchSpec, inplane: float
):
    """Patch pixel -> frame pixel, and each patch pixel's ray z in the frame's camera (for depth)."""
    ray = np.linalg.inv(K) @ np.array([centre_uv[0], centre_uv[1], 1.0])
    rot = align_rotation(ray) @ roll_rotation(inplane)  # virtual camera directions -> frame camera
    Kv_inv = np.linalg.inv(patch_camera(spec, distance_mm))
    H = K @ rot @ Kv_inv
    return H / H[2, 2], rot, Kv_inv


def crop(
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    K: np.ndarray,
    centre_uv: tuple[float, float],
    distance_mm: float,
    spec: PatchSpec = PatchSpec(),
    inplane: float = 0.0,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Cuts the metric window centred on pixel `centre_uv` of an object `distance_mm` away.

    `inplane` (degrees) is undone: an object rolled by it in the frame comes out upright.
    Returns (rgb (S, S, 3) uint8 or None, depth (S, S) float32 mm along the virtual axis or None)."""
    H, rot, Kv_inv = _homography(np.asarray(K, float), centre_uv, distance_mm, spec, inplane)
    s = spec.size
    flags = cv2.WARP_INVERSE_MAP
    rgb_out = depth_out = None
    if rgb is not None:
        rgb_out = cv2.warpPerspective(
            rgb, H, (s, s), flags=cv2.INTER_LINEAR | flags, borderMode=cv2.BORDER_REPLICATE
        )
    if depth is not None:
        d = cv2.warpPerspective(
            depth.astype(np.float32), H, (s, s), flags=cv2.INTER_NEAREST | flags, borderValue=0.0
        )
        # A point at frame depth D along a virtual ray with frame-camera direction r (r_z of the ray
        # through the virtual pixel, scaled so the virtual z is 1) has virtual depth D / r_z.
        u, v = np.meshgrid(np.arange(s, dtype=float), np.arange(s, dtype=float))
        dirs = rot @ Kv_inv @ np.stack([u.ravel(), v.ravel(), np.ones(s * s)])
        depth_out = (d / dirs[2].reshape(s, s)).astype(np.float32)
    return rgb_out, depth_out


def fill_depth(depth: np.ndarray, max_iterations: int = 200) -> np.ndarray:
    """Fills zeros with the median of the valid 3x3 neighbours, repeated until the holes close."""
    d = depth.astype(np.float32).copy()
    holes = d <= 0
    if not holes.any() or holes.all():
        return d
    for _ in range(max_iterations):
        padded = np.pad(np.where(d > 0, d, np.nan), 1, constant_values=np.nan)
        h, w = d.shape
        stack = np.stack([padded[i : i + h, j : j + w] for i in range(3) for j in range(3)])
        valid = np.isfinite(stack).any(axis=0)
        todo = (d <= 0) & valid
        if not todo.any():
            break
        with np.errstate(all="ignore"):
            med = np.nanmedian(stack[:, todo], axis=0)
        d[todo] = med
        if (d > 0).all():
            break
    return d


def surface_depth(depth: np.ndarray, nominal_mm: float, window_mm: float) -> float:
    """Depth of the object's surface at the patch centre: median of the valid depths in the central
    quarter that lie within half a window of `nominal_mm`; `nominal_mm` when there are none.

    Depth is normalised relative to this rather than to the object's origin, because a user of the
    service knows where the object is in the image but not how deep its origin lies behind its surface;
    templates use the same rule, so both sides agree by construction."""
    s = depth.shape[0]
    q = depth[3 * s // 8 : 5 * s // 8, 3 * s // 8 : 5 * s // 8]
    near = q[(q > 0) & (np.abs(q - nominal_mm) < window_mm / 2)]
    return float(np.median(near)) if near.size else float(nominal_mm)


def normalise_depth(depth: np.ndarray, centre_mm: float, window_mm: float) -> np.ndarray:
    """(depth - centre) / (window / 2), clipped to [-1, 1]; empty pixels (0) are far: +1."""
    out = np.clip((depth - centre_mm) / (window_mm / 2), -1.0, 1.0)
    out[depth <= 0] = 1.0
    return out.astype(np.float32)


def normalise_rgb(rgb: np.ndarray) -> np.ndarray:
    """Per channel zero mean, unit variance. Shape: (S, S, 3) uint8 -> (3, S, S) float32."""
    x = rgb.astype(np.float32).reshape(-1, 3)
    x = (x - x.mean(axis=0)) / (x.std(axis=0) + 1e-3 * 255)
    return x.reshape(rgb.shape).transpose(2, 0, 1).astype(np.float32)


def network_input(
    modality: str,
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    nominal_mm: float,
    window_mm: float,
    fill: bool = True,
) -> np.ndarray:
    """One patch as the network takes it. Shape: (C, S, S) float32, C = 3 (rgb), 1 (depth), 4 (rgbd).

    `fill` closes sensor holes first (real and simulated sensors); clean renders pass False, since
    their zeros are background, not missing measurements."""
    parts = []
    if modality in ("rgb", "rgbd"):
        if rgb is None:
            raise ValueError(f"modality {modality} needs an RGB image")
        parts.append(normalise_rgb(rgb))
    if modality in ("depth", "rgbd"):
        if depth is None:
            raise ValueError(f"modality {modality} needs a depth image")
        d = fill_depth(depth) if fill else depth
        centre = surface_depth(d, nominal_mm, window_mm)
        parts.append(normalise_depth(d, centre, window_mm)[None])
    if not parts:
        raise ValueError(f"unknown modality {modality!r}; use one of {sorted(MODALITY_CHANNELS)}")
    return np.concatenate(parts, axis=0)


def batch_inputs(
    modality: str,
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    nominal_mm: float | np.ndarray,
    window_mm: float,
    fill: bool = True,
) -> np.ndarray:
    """`network_input` over a batch: rgb (N, S, S, 3), depth (N, S, S). Shape: (N, C, S, S)."""
    n = len(rgb if rgb is not None else depth)  # type: ignore[arg-type]
    nominal = np.broadcast_to(np.asarray(nominal_mm, dtype=float), (n,))
    return np.stack(
        [
            network_input(
                modality,
                None if rgb is None else rgb[i],
                None if depth is None else depth[i],
                float(nominal[i]),
                window_mm,
                fill,
            )
            for i in range(n)
        ]
    )
