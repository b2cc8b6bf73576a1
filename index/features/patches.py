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
The normalising functions also take a batch, a leading (N) or (*) (`batch_inputs`: (N, C, S, S)), and
work on the whole batch at once: a single patch goes through the same code with N = 1.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import overload

import cv2
import numpy as np

from index.geometry.pose import align_rotation, roll_rotation

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


def _homographies(
    K: np.ndarray,
    centre_uv: tuple[float, float],
    distance_mm: float,
    spec: PatchSpec,
    inplanes: Sequence[float] | np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Patch pixel -> frame pixel for each in-plane (N, 3, 3), the virtual camera's directions in the
    frame's camera (N, 3, 3; their z scales depth) and the virtual camera's inverse (3, 3). The ray, its
    alignment and the virtual camera are computed once: only the roll about the patch's axis differs."""
    ray = np.linalg.inv(K) @ np.array([centre_uv[0], centre_uv[1], 1.0])
    roll = np.stack([roll_rotation(float(a)) for a in inplanes]).reshape(-1, 3, 3)
    rots = align_rotation(ray) @ roll  # virtual camera directions -> frame camera
    Kv_inv = np.linalg.inv(patch_camera(spec, distance_mm))
    Hs = K @ rots @ Kv_inv
    return Hs / Hs[:, 2:3, 2:3], rots, Kv_inv


# What is given comes back cut, what is None stays None.
@overload
def crop(
    rgb: np.ndarray,
    depth: np.ndarray,
    K: np.ndarray,
    centre_uv: tuple[float, float],
    distance_mm: float,
    spec: PatchSpec = PatchSpec(),
    inplane: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def crop(
    rgb: np.ndarray,
    depth: None,
    K: np.ndarray,
    centre_uv: tuple[float, float],
    distance_mm: float,
    spec: PatchSpec = PatchSpec(),
    inplane: float = 0.0,
) -> tuple[np.ndarray, None]: ...
@overload
def crop(
    rgb: None,
    depth: np.ndarray,
    K: np.ndarray,
    centre_uv: tuple[float, float],
    distance_mm: float,
    spec: PatchSpec = PatchSpec(),
    inplane: float = 0.0,
) -> tuple[None, np.ndarray]: ...
@overload
def crop(
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    K: np.ndarray,
    centre_uv: tuple[float, float],
    distance_mm: float,
    spec: PatchSpec = PatchSpec(),
    inplane: float = 0.0,
) -> tuple[np.ndarray | None, np.ndarray | None]: ...
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
    rgbs, depths = crops(rgb, depth, K, centre_uv, distance_mm, spec, [inplane])
    return (None if rgbs is None else rgbs[0]), (None if depths is None else depths[0])


def crops(
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    K: np.ndarray,
    centre_uv: tuple[float, float],
    distance_mm: float,
    spec: PatchSpec,
    inplanes: Sequence[float] | np.ndarray,
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """`crop` at each of `inplanes`, the geometry computed once (a query cut at a dozen rolls: the
    per-crop matrix algebra cost more than the warps). Shape: (N, S, S, 3) uint8, (N, S, S) float32."""
    Hs, rots, Kv_inv = _homographies(np.asarray(K, float), centre_uv, distance_mm, spec, inplanes)
    s = spec.size
    flags = cv2.WARP_INVERSE_MAP
    rgb_out = depth_out = None
    if rgb is not None:
        rgb_out = np.empty((len(Hs), s, s, 3), np.uint8)
        for i, H in enumerate(Hs):
            rgb_out[i] = cv2.warpPerspective(
                rgb, H, (s, s), flags=cv2.INTER_LINEAR | flags, borderMode=cv2.BORDER_REPLICATE
            )
    if depth is not None:
        frame = np.asarray(depth, np.float32)  # only read: no copy of a float32 frame
        u, v = np.meshgrid(np.arange(s, dtype=float), np.arange(s, dtype=float))
        pixels = Kv_inv @ np.stack([u.ravel(), v.ravel(), np.ones(s * s)])
        depth_out = np.empty((len(Hs), s, s), np.float32)
        for i, H in enumerate(Hs):
            d = cv2.warpPerspective(frame, H, (s, s), flags=cv2.INTER_NEAREST | flags, borderValue=0.0)
            # A point at frame depth D along a virtual ray with frame-camera direction r (r_z of the ray
            # through the virtual pixel, scaled so the virtual z is 1) has virtual depth D / r_z.
            depth_out[i] = d / (rots[i][2] @ pixels).reshape(s, s)
    return rgb_out, depth_out


def turn_masks(masks: np.ndarray, degrees: float, spec: PatchSpec = PatchSpec()) -> np.ndarray:
    """Masks of patches cut at in-plane a -> those of the same patches cut at a + `degrees` (`crop`):
    patches of one centre and distance that differ in in-plane differ by a rotation about the patch's
    centre, whatever the frame's camera (the frame's homographies cancel). What the turn brings in from
    outside the patch is False. Shape: (N, S, S) bool -> (N, S, S) bool."""
    kv = patch_camera(spec, 1.0)  # the distance cancels too
    m = kv @ roll_rotation(degrees) @ np.linalg.inv(kv)
    s = spec.size
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    out = [cv2.warpAffine(x.astype(np.float32), m[:2], (s, s), flags=flags, borderValue=0.0) for x in masks]
    return np.stack(out) > 0.5 if out else np.zeros((0, s, s), bool)


def _median_of_valid(values: np.ndarray) -> np.ndarray:
    """Row-wise median of the non-NaN values, as `np.nanmedian` (mean of the two middle ones when even).
    Shape: (N, K) -> (N,), NaN where a row has none. Sorting once beats `nanmedian` on many short rows."""
    ordered = np.sort(values, axis=1)  # NaNs sort last
    k = np.count_nonzero(~np.isnan(values), axis=1)
    rows = np.arange(len(values))
    lo, hi = ordered[rows, np.maximum(k - 1, 0) // 2], ordered[rows, k // 2]
    return np.where(k > 0, (lo + hi) / 2, np.nan)


def fill_depth(depth: np.ndarray, max_iterations: int = 200, needed: np.ndarray | None = None) -> np.ndarray:
    """Fills zeros with the median of the valid 3x3 neighbours, repeated until the holes close.

    Each patch on its own; one without holes or without any depth comes back as it was. `needed` (the
    shape of `depth`, bool): only these pixels must be filled, a patch stops once they are (each round
    fills from the round before, so they hold what the whole fill gives them; holes elsewhere may stay
    zero): a masked query's patch, whose mask empties the rest (`service.pipeline.mask`), 659 -> 88 ms of
    fills a frame of the RGB-D detection on the real Kinect frame.
    Shape: (*, H, W) mm -> (*, H, W) float32."""
    d = np.array(depth, dtype=np.float32)  # a copy
    flat = d.reshape(-1, *d.shape[-2:])  # a view of d: (N, H, W)
    h, w = flat.shape[1:]
    holes = flat <= 0
    want = holes if needed is None else holes & np.reshape(needed, flat.shape)
    active = np.flatnonzero(want.any(axis=(1, 2)) & ~holes.all(axis=(1, 2)))
    if not active.size:
        return d
    sub, want = flat[active], want[active]
    # the valid depths with a border of NaN, kept from round to round: each round writes its fills in
    padded = np.full((len(active), h + 2, w + 2), np.nan, np.float32)
    np.copyto(padded[:, 1:-1, 1:-1], sub, where=sub > 0)
    window = np.array([i * (w + 2) + j for i in range(3) for j in range(3)])  # 3x3, in padded, flat
    for _ in range(max_iterations):
        valid = ~np.isnan(padded)
        near = np.zeros(sub.shape, bool)
        for i in range(3):
            for j in range(3):
                near |= valid[:, i : i + h, j : j + w]
        todo = np.flatnonzero((sub <= 0) & near)
        if not todo.size:
            break
        m, yx = np.divmod(todo, h * w)
        y, x = np.divmod(yx, w)
        corner = (m * (h + 2) + y) * (w + 2) + x  # the pixel's 3x3 neighbourhood starts here in padded
        values = _median_of_valid(padded.reshape(-1)[corner[:, None] + window])
        sub.reshape(-1)[todo] = values
        padded.reshape(-1)[corner + w + 3] = values  # the pixel itself, one row and column in
        want.reshape(-1)[todo] = False
        # a patch stops once what it needs is full, or once no hole has a valid neighbour
        progressed = np.zeros(len(active), bool)
        progressed[m] = True
        going = progressed & want.any(axis=(1, 2))
        if not going.all():
            flat[active] = sub
            active, sub, want, padded = active[going], sub[going], want[going], padded[going]
    flat[active] = sub
    return d


def surface_depth(depth: np.ndarray, nominal_mm: float | np.ndarray, window_mm: float) -> np.ndarray:
    """Depth of the object's surface at the patch centre: median of the valid depths in the central
    quarter that lie within half a window of `nominal_mm`; `nominal_mm` when there are none.
    Shape: depth (*, S, S) mm, nominal_mm () or (*) -> (*) mm, in depth's float type.

    Depth is normalised relative to this rather than to the object's origin, because a user of the
    service knows where the object is in the image but not how deep its origin lies behind its surface;
    templates use the same rule, so both sides agree by construction."""
    depth = np.asarray(depth)
    dtype = np.result_type(depth.dtype, np.float32)
    s = depth.shape[-1]
    q = depth[..., 3 * s // 8 : 5 * s // 8, 3 * s // 8 : 5 * s // 8].astype(dtype)
    q = q.reshape(*q.shape[:-2], q.shape[-2] * q.shape[-1])
    nominal = np.broadcast_to(np.asarray(nominal_mm, dtype), q.shape[:-1])
    near = (q > 0) & (np.abs(q - nominal[..., None]) < window_mm / 2)
    med = _median_of_valid(np.where(near, q, np.nan).reshape(-1, q.shape[-1])).reshape(nominal.shape)
    return np.where(np.isnan(med), nominal, med).astype(dtype)


def normalise_depth(depth: np.ndarray, centre_mm: float | np.ndarray, window_mm: float) -> np.ndarray:
    """(depth - centre) / (window / 2), clipped to [-1, 1]; empty pixels (0) are far: +1.
    Shape: depth (*, S, S) mm, centre_mm () or (*) -> (*, S, S) float32."""
    depth = np.asarray(depth)
    centre = np.asarray(centre_mm, np.result_type(depth.dtype, np.float32))[..., None, None]
    out = np.clip((depth - centre) / (window_mm / 2), -1.0, 1.0)
    out[depth <= 0] = 1.0
    return out.astype(np.float32)


def normalise_rgb(rgb: np.ndarray) -> np.ndarray:
    """Per patch and channel zero mean, unit variance. Shape: (*, S, S, 3) uint8 -> (*, 3, S, S) float32."""
    x = np.moveaxis(rgb, -1, -3).astype(np.float32, order="C")  # channels first, so each mean is contiguous
    x -= x.mean(axis=(-2, -1), keepdims=True)
    # the standard deviation as `np.std` computes it (the same sums in the same order: the same bits),
    # from the values centred once rather than twice: a fifth less time for a registration's templates
    std = np.add.reduce(np.square(x), axis=(-2, -1), keepdims=True)
    std /= x.shape[-2] * x.shape[-1]
    np.sqrt(std, out=std)
    std += 1e-3 * 255
    x /= std
    return x


def network_input(
    modality: str,
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    nominal_mm: float,
    window_mm: float,
    fill: bool = True,
) -> np.ndarray:
    """One patch as the network takes it: `batch_inputs` with N = 1.
    Shape: rgb (S, S, 3), depth (S, S) -> (C, S, S) float32, C = 3 (rgb), 1 (depth), 4 (rgbd).

    `fill` closes sensor holes first (real and simulated sensors); clean renders pass False, since
    their zeros are background, not missing measurements."""
    for name, image, shape in (("rgb", rgb, "(S, S, 3)"), ("depth", depth, "(S, S)")):
        if image is not None and np.ndim(image) != shape.count(",") + 1:
            raise ValueError(f"one {name} patch must be {shape}, got {np.shape(image)}")
    return batch_inputs(
        modality,
        None if rgb is None else np.asarray(rgb)[None],
        None if depth is None else np.asarray(depth)[None],
        nominal_mm,
        window_mm,
        fill,
    )[0]


def batch_inputs(
    modality: str,
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    nominal_mm: float | np.ndarray,
    window_mm: float,
    fill: bool = True,
) -> np.ndarray:
    """Patches as the network takes them, all at once.
    Shape: rgb (N, S, S, 3) uint8, depth (N, S, S) mm, nominal_mm () or (N) -> (N, C, S, S) float32,
    C = 3 (rgb), 1 (depth), 4 (rgbd)."""
    if modality not in MODALITY_CHANNELS:
        raise ValueError(f"unknown modality {modality!r}; use one of {sorted(MODALITY_CHANNELS)}")
    colour, ranged = modality in ("rgb", "rgbd"), modality in ("depth", "rgbd")
    if colour and rgb is None:
        raise ValueError(f"modality {modality} needs an RGB image")
    if ranged and depth is None:
        raise ValueError(f"modality {modality} needs a depth image")
    rgb = np.asarray(rgb) if colour else None
    depth = np.asarray(depth) if ranged else None
    if rgb is not None and (rgb.ndim != 4 or rgb.shape[3] != 3 or rgb.shape[1] != rgb.shape[2]):
        raise ValueError(f"rgb patches must be (N, S, S, 3), got {rgb.shape}")
    if depth is not None and (depth.ndim != 3 or depth.shape[1] != depth.shape[2]):
        raise ValueError(f"depth patches must be (N, S, S), got {depth.shape}")
    if rgb is not None and depth is not None and rgb.shape[:3] != depth.shape:
        raise ValueError(f"rgb {rgb.shape} and depth {depth.shape} patches differ in number or size")
    n = len(rgb if rgb is not None else depth)  # type: ignore[arg-type]
    nominal = np.broadcast_to(np.asarray(nominal_mm, float), (n,))

    parts = []
    if rgb is not None:
        parts.append(normalise_rgb(rgb))
    if depth is not None:
        d = fill_depth(depth) if fill else depth
        parts.append(normalise_depth(d, surface_depth(d, nominal, window_mm), window_mm)[:, None])
    return np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]
