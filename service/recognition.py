"""One recognition: decoded images -> the model's patch -> descriptor -> nearest templates.

Runs in a worker thread (never on the event loop) and never waits on a registration: it reads the
store's current snapshot and runs the model's own onnxruntime session."""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from index.patches import crop
from index.store import Match
from service.errors import ApiError
from service.images import read_depth, read_rgb
from service.state import AppState

FRAME_FIELDS = ("fx", "fy", "cx", "cy", "u", "v")
MAX_PX = 1e6  # focal lengths and image coordinates beyond this are no camera's
MIN_DISTANCE_MM, MAX_DISTANCE_MM = 1.0, 100_000.0  # the object's distance, given or measured


@dataclass(frozen=True)
class Query:
    rgb: bytes | None
    depth: bytes | None
    depth_scale: float = 1.0
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    u: float | None = None
    v: float | None = None
    distance_mm: float | None = None
    k: int = 5


@dataclass
class Result:
    model: str
    matches: list[Match]
    timings_ms: dict[str, float]


def recognise(state: AppState, q: Query) -> Result:
    t0 = time.perf_counter()
    if q.k > state.settings.max_k:
        raise ApiError(422, f"k: must be at most {state.settings.max_k}, got {q.k}")
    if q.rgb is None and q.depth is None:
        raise ApiError(422, "send an `rgb` image, a `depth` image, or both")
    modality = (
        "rgbd" if q.rgb is not None and q.depth is not None else "rgb" if q.rgb is not None else "depth"
    )
    embedder = state.embedders.get(modality)
    if embedder is None:
        loaded = ", ".join(sorted(state.embedders))
        raise ApiError(422, f"no {modality} model is loaded (loaded: {loaded}); send what one of them takes")
    px = state.settings.max_image_pixels
    rgb = None if q.rgb is None else read_rgb(q.rgb, px)
    depth = None if q.depth is None else read_depth(q.depth, q.depth_scale, px)
    if rgb is not None and depth is not None and rgb.shape[:2] != depth.shape:
        raise ApiError(
            422,
            f"rgb is {rgb.shape[1]} x {rgb.shape[0]} px but depth is {depth.shape[1]} x {depth.shape[0]} px",
        )
    t1 = time.perf_counter()
    spec = embedder.info.spec
    given = [f for f in FRAME_FIELDS if getattr(q, f) is not None]
    if given and len(given) < len(FRAME_FIELDS):
        missing = ", ".join(f for f in FRAME_FIELDS if f not in given)
        raise ApiError(422, f"a full frame needs fx, fy, cx, cy, u and v; missing: {missing}")
    if given:
        rgb_p, depth_p, distance = _from_frame(q, rgb, depth, spec)
    else:
        rgb_p, depth_p, distance = _from_patch(q, rgb, depth, spec.size)
    if depth_p is not None and not (depth_p > 0).any():
        raise ApiError(422, "the depth patch is all zero: no depth was measured around the object")
    t2 = time.perf_counter()
    desc = embedder.embed_patches(
        None if rgb_p is None else rgb_p[None],
        None if depth_p is None else depth_p[None],
        distance,
        fill=True,
    )
    t3 = time.perf_counter()
    (matches,) = state.store.snapshot.search(modality, desc, q.k)
    t4 = time.perf_counter()
    ms = {"decode": t1 - t0, "patch": t2 - t1, "embed": t3 - t2, "search": t4 - t3, "total": t4 - t0}
    return Result(state.model_names[modality], matches, {k: round(v * 1000, 2) for k, v in ms.items()})


def _from_frame(q: Query, rgb, depth, spec):
    h, w = (rgb if rgb is not None else depth).shape[:2]
    u, v = float(q.u), float(q.v)  # type: ignore[arg-type]
    if not (0 <= u < w and 0 <= v < h):
        raise ApiError(422, f"the centre (u, v) = ({u:g}, {v:g}) is outside the {w} x {h} frame")
    K = np.array([[q.fx, 0.0, q.cx], [0.0, q.fy, q.cy], [0.0, 0.0, 1.0]], dtype=float)
    distance = q.distance_mm
    if distance is None:
        if depth is None:
            raise ApiError(422, "a colour-only frame needs distance_mm (the object's distance, mm)")
        distance = _measured(_depth_at(depth, K, u, v))
    rgb_p, depth_p = crop(rgb, depth, K, (u, v), distance, spec)
    return rgb_p, depth_p, distance


def _depth_at(depth: np.ndarray, K: np.ndarray, u: float, v: float, r: int = 7) -> float:
    """Distance (mm, along the ray) of the surface at (u, v): median of the valid depths around it."""
    iu, iv = int(u), int(v)
    win = depth[max(0, iv - r) : iv + r + 1, max(0, iu - r) : iu + r + 1]
    valid = win[win > 0]
    if valid.size == 0:
        raise ApiError(422, f"no depth around the centre ({u:g}, {v:g}); send distance_mm")
    ray = np.linalg.inv(K) @ np.array([u, v, 1.0])
    return float(np.median(valid) * np.linalg.norm(ray))


def _from_patch(q: Query, rgb, depth, size: int):
    """A patch already centred on the object, spanning the model's metric window: resized to the input."""
    h, w = (rgb if rgb is not None else depth).shape[:2]
    if abs(h - w) > 1:
        raise ApiError(
            422, f"a patch must be square ({w} x {h} px); for a full frame send fx, fy, cx, cy, u and v"
        )
    rgb_p = None if rgb is None else cv2.resize(rgb, (size, size), interpolation=cv2.INTER_AREA)
    depth_p = None if depth is None else cv2.resize(depth, (size, size), interpolation=cv2.INTER_NEAREST)
    distance = q.distance_mm
    if distance is None and depth_p is not None:
        c = depth_p[size * 3 // 8 : size * 5 // 8, size * 3 // 8 : size * 5 // 8]
        distance = _measured(float(np.median(c[c > 0]))) if (c > 0).any() else None
    return rgb_p, depth_p, distance or 400.0


def _measured(distance: float) -> float:
    if not MIN_DISTANCE_MM <= distance <= MAX_DISTANCE_MM:
        raise ApiError(
            422,
            f"the depth at the centre says {distance:.3g} mm, outside {MIN_DISTANCE_MM:g} to "
            f"{MAX_DISTANCE_MM:g} mm: is depth_scale right?",
        )
    return distance
