"""The camera as the field writes it: `cam_K`, the 3 x 3 matrix row-major (OpenCV's, BOP's `cam_K`), instead of
fx, fy, cx, cy; and OpenCV's distortion coefficients (`dist_coeffs`: k1 k2 p1 p2 [k3 [k4 k5 k6 [s1 s2 s3 s4
[tx ty]]]]). A distorted frame is undistorted before anything else, onto the same K: its colour bilinearly,
its depth by the nearest measurement (a depth between two surfaces is no surface), and the centre sent with
it moved as its pixel moves. Every pixel of the answer is then of the undistorted frame."""

from __future__ import annotations

import re

import cv2
import numpy as np

from service.errors import ApiError

#: the lengths OpenCV takes
DIST_LENGTHS = (4, 5, 8, 12, 14)
#: focal lengths and image coordinates beyond this are no camera's (fx and fy are at least 1 px: the form's
#: fields and `cam_K` alike, so every camera matrix the service makes can be inverted)
MAX_PX = 1e6


def numbers(text: str, name: str) -> list[float]:
    """`text` as numbers: separated by commas or spaces, with or without brackets (a JSON list, a row of
    a file); refused (422) naming the field when a part is no finite number."""
    parts = [p for p in re.split(r"[\s,;\[\]()]+", text.strip()) if p]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ApiError(
            422, f"{name}: {text[:80]!r} is not a list of numbers (e.g. 572.4,0,325.3,...)"
        ) from None
    if not all(np.isfinite(values)):
        raise ApiError(422, f"{name}: every number must be finite, got {text[:80]!r}")
    return values


def intrinsics(cam_k: str) -> tuple[float, float, float, float]:
    """fx, fy, cx, cy of a `cam_K` (9 numbers, row-major); refused when it is no pinhole camera's matrix."""
    k = numbers(cam_k, "cam_K")
    if len(k) != 9:
        raise ApiError(
            422, f"cam_K: 9 numbers, the 3 x 3 matrix row by row (fx 0 cx 0 fy cy 0 0 1), got {len(k)}"
        )
    K = np.array(k).reshape(3, 3)
    if not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0 or abs(K[0, 1]) > 1e-6 * abs(K[0, 0]):
        raise ApiError(
            422,
            "cam_K: a pinhole camera's matrix is fx 0 cx / 0 fy cy / 0 0 1 (no skew), row by row; got "
            + " ".join(f"{x:g}" for x in k),
        )
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    if not (1.0 <= fx <= MAX_PX and 1.0 <= fy <= MAX_PX):
        raise ApiError(
            422, f"cam_K: the focal lengths fx and fy must be 1 to {MAX_PX:g} px, got fx {fx:g}, fy {fy:g}"
        )
    if not (abs(cx) <= MAX_PX and abs(cy) <= MAX_PX):
        raise ApiError(
            422, f"cam_K: the principal point must lie within {MAX_PX:g} px, got cx {cx:g}, cy {cy:g}"
        )
    return fx, fy, cx, cy


def coefficients(dist: str) -> tuple[float, ...] | None:
    """OpenCV's distortion coefficients, or None when all are 0 (nothing to undo)."""
    d = numbers(dist, "dist_coeffs")
    if len(d) not in DIST_LENGTHS:
        raise ApiError(
            422,
            f"dist_coeffs: OpenCV's order takes 4, 5, 8, 12 or 14 numbers (k1 k2 p1 p2 [k3 ...]), got {len(d)}",
        )
    return tuple(d) if any(d) else None


def undistorted_point(u: float, v: float, K: np.ndarray, dist: tuple[float, ...]) -> tuple[float, float]:
    """Where pixel (u, v) of the distorted frame lies in the undistorted one (the same K)."""
    p = cv2.undistortPoints(np.array([[[u, v]]], np.float64), K, np.array(dist), P=K)
    return float(p[0, 0, 0]), float(p[0, 0, 1])


def undistorted(
    rgb: np.ndarray | None, depth: np.ndarray | None, K: np.ndarray, dist: tuple[float, ...]
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The frame's images undistorted onto K: colour bilinear, depth nearest (0 where nothing maps)."""
    h, w = (rgb if rgb is not None else depth).shape[:2]  # type: ignore[union-attr]
    mx, my = cv2.initUndistortRectifyMap(K, np.array(dist), None, K, (w, h), cv2.CV_32FC1)
    out_rgb = (
        None if rgb is None else cv2.remap(rgb, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    )
    out_depth = (
        None if depth is None else cv2.remap(depth, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
    )
    return out_rgb, out_depth
