"""Where objects may be in a depth frame: candidate centres, distances and boxes, no model needed.

The frame is back-projected to points (every stride-th pixel), the large planes the objects stand on
(and the floor or walls behind them) are found by RANSAC and removed, and what is left is cut into
segments where neighbouring pixels' depths jump, at three thresholds (objects that touch often meet at a
small step only). Each segment of a plausible size becomes a proposal; the few larger than any object
looked for, standing on the support, are also cut into 2, 3 and 4 parts by k-means (a real sensor joins
touching objects). Everything is in mm, OpenCV camera axes (x right, y down, z forward); `depth` holds z,
0 where the sensor measured nothing. The frame sampled and its planes found (`depth_scene`) also give the
support (`Support`), against which a pose that stands through the table is told (`Support.sunk`).

Measured by scripts/depth_proposals_eval.py (docs/results/depth_proposals.json; the script is in the history
at 36ee81d): on the real Kinect frame
of LM-O 5 of its 6 instances with visib_fract >= 0.5 in the first 30 proposals, all 6 in the first 50.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np

# Pixels are taken STRIDE apart on a 640-wide frame (wider frames proportionally more): a 20 mm object at
# 2 m is still 3 samples across, and a 640 x 480 frame costs 76,800 points instead of 307,200.
STRIDE_WIDTH = 320
# A point lies on a plane within PLANE_TOL_MM + PLANE_TOL_REL * z: the Kinect's depth steps (z^2 / 348,000
# mm: 3 mm at 1 m, 6.5 mm at 1.5 m) and noise (sigma 1.2 + 1.9 (z/m - 0.4)^2 mm: 2 mm at 1 m), with room
# for a board lying on the table.
PLANE_TOL_MM, PLANE_TOL_REL = 4.0, 0.008
RANSAC_SAMPLE = 1024  # points the hypotheses are scored on
RANSAC_HYPOTHESES = 128  # a plane holding 20 % of the points is hit by a triple with chance 1 - 0.992^128
MAX_PLANES = 3  # the table, the floor beyond it, a wall
# A plane is a support (or background) only when it holds this share of the measured points and covers
# this area: larger than any face of a tabletop object (LineMOD's largest, the driller, is 261 mm across),
# so an object's flat side seen alone is not taken for the table.
SUPPORT_MIN_SHARE = 0.08
SUPPORT_MIN_AREA_MM2 = 0.1e6
# Of a plane after the first (the support) only connected pieces this large are removed: a plane through
# the table's far side also passes through the tops of objects standing nearer, which must stay.
PIECE_MIN_AREA_MM2 = 0.03e6
# Neighbouring pixels belong to one segment while their depths differ by less than this share of the depth:
# the loose level keeps an object whole over its own creases and slants, the tight ones part objects that
# touch at a small step (on the real frame the egg box under the toy car parts at 0.005 only; a 0.04 level
# added nothing, 0.02/0.01/0.005 lost two instances; 0.005 is about the Kinect's quantisation step at 1.2 m).
STEP_LEVELS = (0.015, 0.008, 0.005)
MIN_SEGMENT_PX = 10  # sampled pixels; fewer is sensor noise or a sliver
# Proposals that overlap this much (box IoU) with a better one, centres within a quarter box, are dropped
# (0.7 kept the same recall with 10 more proposals).
SAME_IOU = 0.5
# A segment larger than any registered object can show (`largest_mm`; without it, two typical objects),
# standing on the support, may be objects that touch without a step between them: real sensors smooth
# the depth over an occluding edge, so that touching objects meet at no step (YCB-V video 0002: a wood
# block, a banana, a box on it and a can before it made one segment at every level). The MAX_SPLIT largest
# such are also cut into 2, 3, ... MAX_PARTS parts by k-means on their points (how many objects a segment
# holds is not known: every count is proposed), each part with its score times PART_WEIGHT.
MAX_SPLIT, MAX_PARTS, PART_WEIGHT = 4, 4, 0.5
# An object's visible surface spans about this share of its diameter: the largest side of the visible box
# of LM-O's annotated instances at least half visible, in mm at their distance, over the diameter (all
# scenes' 562 instances: median 0.86, 0.74-0.98 from the 10th to the 90th percentile)
VISIBLE_SHARE = 0.86
KMEANS_SAMPLE, KMEANS_ROUNDS = 500, 6
BELOW_SUPPORT = 0.5  # score factor of segments wholly beneath the support (beyond the table's edge)
AT_BORDER = 0.6  # and of segments the image's border cuts off
# A pose stands through the support where its surface lies deeper below the plane than this many times the
# plane's own tolerance (`_tolerance`: 12 mm at 1 m, so 30 mm): on YCB-V's real depth the right detections'
# surfaces reach 7-27 mm below the table found (the plane's noise and the fit's), the cracker box fitted
# to a keyboard's top 37-780 mm (docs/experiments.md, "Poses through the table").
SUNK_TOLERANCE = 2.5


@dataclass(frozen=True)
class Segment:
    """A candidate object. u, v: where its centre projects (px); distance_mm: camera to the centre;
    box: x0, y0, x1, y1 px of its visible surface; score: higher is more object-like (0..1); part: a part
    of a segment larger than any object looked for (`largest_mm`), a guess at where one object ends."""

    u: float
    v: float
    distance_mm: float
    box: tuple[float, float, float, float]
    score: float
    part: bool = False


@dataclass(frozen=True)
class _Frame:
    points: np.ndarray  # (h * w, 3) of the sampled pixels, row-major
    shape: tuple[int, int]  # h, w sampled
    stride: int
    K: np.ndarray
    support: _Plane | None


@dataclass(frozen=True)
class _Found:
    """Proposals as arrays: uv (N, 2), distance (N,), box (N, 4), score (N,), part (N,: a part of a larger
    segment); and the segments too large for one object: (flat pixel indices, size mm)."""

    uv: np.ndarray
    distance: np.ndarray
    box: np.ndarray
    score: np.ndarray
    large: list[tuple[np.ndarray, float]]
    part: np.ndarray

    @staticmethod
    def empty() -> _Found:
        return _Found(np.zeros((0, 2)), np.zeros(0), np.zeros((0, 4)), np.zeros(0), [], np.zeros(0, bool))

    @staticmethod
    def concat(parts: list[_Found]) -> _Found:
        return _Found(
            np.concatenate([f.uv for f in parts]),
            np.concatenate([f.distance for f in parts]),
            np.concatenate([f.box for f in parts]),
            np.concatenate([f.score for f in parts]),
            [],
            np.concatenate([f.part for f in parts]),
        )


@dataclass(frozen=True)
class _Plane:
    normal: np.ndarray  # (3,), facing the camera
    offset: float  # normal . X = offset on the plane (negative: the camera is on the normal's side)

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed distance of points (..., 3) from the plane, positive on the camera's side."""
        return points @ self.normal - self.offset


def depth_proposals(
    depth: np.ndarray,
    K: np.ndarray,
    *,
    min_size_mm: float = 20.0,
    max_size_mm: float = 2000.0,
    limit: int = 30,
    largest_mm: float | None = None,
    scene: DepthScene | None = None,
) -> list[Segment]:
    """Candidate objects in a depth frame, best first, at most `limit`.

    depth: (H, W) mm, 0 (or not finite) = no measurement; K: (3, 3) OpenCV intrinsics. An object's size
    is the largest extent of its visible surface; segments outside [min_size_mm, max_size_mm] are not
    proposed (larger ones are split into parts). `largest_mm`: the largest visible extent any object looked
    for can show (`largest_visible`); a larger segment is also proposed in parts (None: larger than two
    objects of the range's typical size). `scene`: `depth_scene(depth, K)`, when the caller has it."""
    if not 0 < min_size_mm < max_size_mm:
        raise ValueError(f"need 0 < min_size_mm < max_size_mm, got {min_size_mm}, {max_size_mm}")
    scene = depth_scene(depth, K) if scene is None else scene
    if scene.readings < MIN_SEGMENT_PX or limit < 1:
        return []
    frame, z = scene.frame, scene.frame.points[:, 2].reshape(scene.frame.shape)
    sizes = (min_size_mm, max_size_mm)
    split = 2 * _typical(sizes) if largest_mm is None else largest_mm
    found = []
    for level in STEP_LEVELS:
        found.append(_describe(frame, _segments(z, (z > 0) & ~scene.on_plane, level), sizes, split))
        if found[-1].large:
            found += [
                _describe(frame, labels, sizes, split, PART_WEIGHT, part=True)
                for labels in _parts(frame, found[-1].large)
            ]
    return _distinct(_Found.concat(found), limit)


@dataclass(frozen=True)
class Support:
    """The plane a frame's objects stand on, where the frame shows it: `plane` (camera axes, mm), `seen`
    ((h, w) bool: the sampled pixels on it, every `stride`-th of the frame's) and the intrinsics `K`."""

    plane: _Plane
    seen: np.ndarray
    stride: int
    K: np.ndarray

    def sunk(self, points: np.ndarray) -> float:
        """The share of `points` ((N, 3) camera axes, mm: an object's surface at a pose) that lie deeper
        below the support than SUNK_TOLERANCE times its tolerance at their depth, at pixels where the frame
        sees the support in front of them: a pose with a share of them stands through the table. Points
        beyond the frame or where it sees something else (the floor past the table's edge) do not count."""
        points = np.asarray(points, float).reshape(-1, 3)
        if not len(points):
            return 0.0
        z = points[:, 2]
        ahead = z > 1e-6
        uv = points[:, :2] / np.where(ahead, z, 1.0)[:, None] * np.diag(self.K)[:2] + self.K[:2, 2]
        col, row = np.round(uv / self.stride).astype(np.int64).T
        h, w = self.seen.shape
        inside = ahead & (col >= 0) & (col < w) & (row >= 0) & (row < h)
        seen = np.zeros(len(points), bool)
        seen[inside] = self.seen[row[inside], col[inside]]
        deep = self.plane.height(points) < -SUNK_TOLERANCE * _tolerance(z)
        return float((deep & seen).mean())


@dataclass(frozen=True)
class DepthScene:
    """A depth frame sampled every `frame.stride`-th pixel, back-projected, its large planes found:
    `on_plane` ((h, w) bool) marks the sampled pixels on any of them, `support` the first and the pixels
    on it (None: none found), `readings` the sampled pixels with a measurement."""

    frame: _Frame
    on_plane: np.ndarray
    readings: int
    support: Support | None = None


def depth_scene(depth: np.ndarray, K: np.ndarray) -> DepthScene:
    """`depth` ((H, W) mm, 0 or not finite: no measurement) sampled, back-projected with the OpenCV
    intrinsics `K` and its planes found: what `depth_proposals` segments and what tells whether a pose
    stands through the table (`Support.sunk`)."""
    depth = np.asarray(depth)
    K = np.asarray(K, float)
    if depth.ndim != 2 or depth.shape[0] < 2 or depth.shape[1] < 2:
        raise ValueError(f"depth must be an (H, W) image, got shape {depth.shape}")
    if K.shape != (3, 3) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError("K must be 3 x 3 intrinsics with positive focal lengths")
    stride = max(1, round(depth.shape[1] / STRIDE_WIDTH))
    z = np.nan_to_num(depth[::stride, ::stride].astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    z[z < 0] = 0.0
    valid = z > 0
    points = _back_project(z, K, stride)
    if valid.sum() < MIN_SEGMENT_PX:
        empty = _Frame(points.reshape(-1, 3), z.shape, stride, K, None)
        return DepthScene(empty, np.zeros(z.shape, bool), int(valid.sum()))
    planes, on_plane, on_support = _planes(points, z, valid, K, stride)
    frame = _Frame(points.reshape(-1, 3), z.shape, stride, K, planes[0] if planes else None)
    support = Support(planes[0], on_support, stride, K) if planes else None
    return DepthScene(frame, on_plane, int(valid.sum()), support)


def largest_visible(diameters_mm: Iterable[float]) -> float | None:
    """The largest visible extent (mm) objects of these diameters show (`VISIBLE_SHARE` of the largest);
    None without any."""
    largest = max(diameters_mm, default=None)
    return None if largest is None else VISIBLE_SHARE * largest


def _back_project(z: np.ndarray, K: np.ndarray, stride: int) -> np.ndarray:
    """Camera-frame points of the sampled pixels. Shape: (h, w) -> (h, w, 3)."""
    h, w = z.shape
    u = np.arange(w, dtype=np.float32) * stride
    v = np.arange(h, dtype=np.float32) * stride
    x = (u[None, :] - K[0, 2]) / K[0, 0] * z
    y = (v[:, None] - K[1, 2]) / K[1, 1] * z
    return np.stack([x, y, z], axis=-1)


def _tolerance(z: np.ndarray) -> np.ndarray:
    return PLANE_TOL_MM + PLANE_TOL_REL * z


def _planes(
    points: np.ndarray, z: np.ndarray, valid: np.ndarray, K: np.ndarray, stride: int
) -> tuple[list[_Plane], np.ndarray, np.ndarray]:
    """The large planes (largest first), the mask of sampled pixels on any of them and the mask of those on
    the first (the support; all False without a plane)."""
    rng = np.random.default_rng(0)  # the same frame gives the same proposals
    on = np.zeros(z.shape, bool)
    first = on
    planes: list[_Plane] = []
    n_valid = int(valid.sum())
    tol = _tolerance(z)
    # the area a sampled pixel covers facing the camera (mm^2), and its ray's length per mm of depth
    pixel_area = (stride * z / K[0, 0]) * (stride * z / K[1, 1])
    ray_length = np.linalg.norm(points, axis=2) / np.maximum(z, 1e-6)
    for _ in range(MAX_PLANES):
        left = valid & ~on
        where = np.flatnonzero(left)
        if len(where) < SUPPORT_MIN_SHARE * n_valid:
            break
        pick = where[rng.integers(0, len(where), RANSAC_SAMPLE)]  # repeats do no harm
        plane = _ransac(points.reshape(-1, 3)[pick], tol.ravel()[pick], rng)
        if plane is None:
            break
        inliers = left & (np.abs(plane.height(points)) < tol)
        if planes:
            inliers = _large_pieces(inliers, pixel_area)
        # a plane seen at a slant covers more than its pixels' area facing the camera (up to 5 times)
        cos = np.abs(points[inliers] @ plane.normal) / (z[inliers] * ray_length[inliers])
        area = float((pixel_area[inliers] / np.maximum(cos, 0.2)).sum())
        if inliers.sum() < SUPPORT_MIN_SHARE * n_valid or area < SUPPORT_MIN_AREA_MM2:
            break
        planes.append(plane)
        on |= inliers
        first = inliers if len(planes) == 1 else first
    return planes, on, first


def _large_pieces(mask: np.ndarray, pixel_area: np.ndarray) -> np.ndarray:
    """The connected parts of `mask` covering at least PIECE_MIN_AREA_MM2 facing the camera."""
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8, ltype=cv2.CV_32S)
    area = np.bincount(labels.ravel(), weights=pixel_area.ravel(), minlength=n)
    big = area >= PIECE_MIN_AREA_MM2
    big[0] = False
    return big[labels]


def _ransac(sample: np.ndarray, sample_tol: np.ndarray, rng: np.random.Generator) -> _Plane | None:
    """The plane through most of the points `sample` (N, 3) within `sample_tol` (N,), refined by least
    squares."""
    triples = sample[rng.integers(0, len(sample), (RANSAC_HYPOTHESES, 3))]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-6
    if not ok.any():
        return None
    normals = normals[ok] / norms[ok, None]
    offsets = np.einsum("ij,ij->i", normals, triples[ok, 0])
    counts = (
        np.abs(sample @ normals.T.astype(np.float32) - offsets.astype(np.float32)) < sample_tol[:, None]
    ).sum(axis=0)
    best = int(np.argmax(counts))
    normal, offset = normals[best], offsets[best]
    for _ in range(2):  # least squares on the inliers, twice (the inlier set moves with the plane)
        near = np.abs(sample @ normal - offset) < sample_tol
        if near.sum() < 3:
            return None
        centre = sample[near].mean(axis=0, dtype=np.float64)
        normal = np.linalg.svd(sample[near] - centre, full_matrices=False)[2][2]
        offset = float(normal @ centre)
    if offset > 0:  # face the camera (at the origin): offset < 0
        normal, offset = -normal, -offset
    return _Plane(normal, float(offset))


def _segments(z: np.ndarray, free: np.ndarray, level: float) -> np.ndarray:
    """Labels (h, w) int32 of the connected parts of `free` (0: none) where neighbours' depths differ by
    less than `level` * z. At a larger step the farther pixel is cut, so the nearer surface stays whole."""
    cut = np.zeros(z.shape, bool)
    for a, b, cut_a, cut_b in (
        (z[:-1], z[1:], cut[:-1], cut[1:]),
        (z[:, :-1], z[:, 1:], cut[:, :-1], cut[:, 1:]),
    ):
        step = (a > 0) & (b > 0) & (np.abs(a - b) > level * np.minimum(a, b))
        cut_a |= step & (a > b)
        cut_b |= step & (b > a)
    _, labels = cv2.connectedComponents((free & ~cut).astype(np.uint8), connectivity=4, ltype=cv2.CV_32S)
    return labels


def _describe(
    frame: _Frame,
    labels: np.ndarray,
    sizes: tuple[float, float],
    split: float,
    weight: float = 1.0,
    part: bool = False,
) -> _Found:
    """The proposals of every segment of `labels` ((h, w) int, 0: none) that may be an object, and the
    segments too large for one (their flat pixel indices): larger than `split` mm."""
    flat = labels.ravel()
    idx = np.flatnonzero(flat)
    lab = flat[idx]
    order = np.argsort(lab, kind="stable")
    idx, lab = idx[order], lab[order]
    if not len(idx):
        return _Found.empty()
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    counts = np.diff(np.r_[starts, len(lab)])
    P = frame.points[idx]
    lo, hi = np.minimum.reduceat(P, starts), np.maximum.reduceat(P, starts)
    size = (hi - lo).max(axis=1)
    rows, cols = np.divmod(idx, frame.shape[1])
    r0, r1 = np.minimum.reduceat(rows, starts), np.maximum.reduceat(rows, starts)
    c0, c1 = np.minimum.reduceat(cols, starts), np.maximum.reduceat(cols, starts)
    # The object's origin (its bounding-box centre) lies behind the visible surface: along the ray through
    # the middle of the surface's extent, half the largest extent across the ray (the likely depth) behind
    # the surface's nearest point, but no lower than half its height above the support (measured against
    # other estimates: scripts/depth_proposals_eval.py's docstring, at 36ee81d).
    mid = (lo + hi) / 2
    ray = mid / np.linalg.norm(mid, axis=1, keepdims=True)
    seg = np.repeat(np.arange(len(starts)), counts)
    near = np.minimum.reduceat(np.einsum("ij,ij->i", P, ray[seg]), starts)
    reach = near + (hi - lo)[:, :2].max(axis=1) / 2
    if frame.support is not None:
        h = frame.support.height(P)
        h_lo, h_hi = np.minimum.reduceat(h, starts), np.maximum.reduceat(h, starts)
        descent = ray @ frame.support.normal  # < 0: the ray goes down towards the support
        with np.errstate(divide="ignore", invalid="ignore"):
            half_height = (h_hi / 2 + frame.support.offset) / descent
        reach = np.where(descent < -0.1, np.maximum(near, np.minimum(reach, half_height)), reach)
    centre = ray * reach[:, None]
    # score: a typical size, a box the segment fills, enough points, not beneath the support
    spread = np.log(sizes[1] / sizes[0]) / 4
    score = np.exp(-0.5 * (np.log(np.maximum(size, 1e-3) / _typical(sizes)) / spread) ** 2)
    fill = counts / ((r1 - r0 + 1) * (c1 - c0 + 1))
    score *= (0.5 + 0.5 * fill) * (1.0 - np.exp(-counts / 40.0))
    keep = (counts >= MIN_SEGMENT_PX) & (size >= sizes[0]) & (size <= sizes[1])
    if frame.support is not None:
        keep &= ~((h_hi < sizes[0]) & (h_lo > -sizes[0]))  # lying flat on it: table, paper
        score *= np.where(h_hi < -sizes[0], BELOW_SUPPORT, 1.0)
    h_, w_ = frame.shape
    cut_off = (r0 == 0) | (c0 == 0) | (r1 == h_ - 1) | (c1 == w_ - 1)
    score *= np.where(cut_off, AT_BORDER, 1.0)
    s = frame.stride
    box = np.stack([c0 * s, r0 * s, (c1 + 1) * s - 1, (r1 + 1) * s - 1], axis=1).astype(float)
    uv = (frame.K @ centre.T).T
    # split: segments larger than any object looked for, on the support (touching objects), a few largest
    large = (counts >= MIN_SEGMENT_PX) & ((size > split) | (size > sizes[1]))
    if frame.support is not None:
        large &= (h_lo < sizes[0]) & (h_hi > sizes[0])
    large &= counts >= np.sort(np.where(large, counts, 0))[-MAX_SPLIT:][0]
    ends = starts + counts
    return _Found(
        uv[keep, :2] / uv[keep, 2:],
        np.linalg.norm(centre[keep], axis=1),
        box[keep],
        score[keep] * weight,
        [(idx[a:b], float(sz)) for a, b, sz, big in zip(starts, ends, size, large, strict=True) if big],
        np.full(int(keep.sum()), part),
    )


def _typical(sizes: tuple[float, float]) -> float:
    """The size the score likes best: the geometric middle of the range (200 mm for 20-2000 mm)."""
    return float(np.sqrt(sizes[0] * sizes[1]))


def _parts(frame: _Frame, large: list[tuple[np.ndarray, float]]) -> list[np.ndarray]:
    """Labels (h, w) of the segments larger than one object cut into k parts each by k-means on their
    points, one labelling for each k from 2 to MAX_PARTS."""
    rng = np.random.default_rng(0)
    out = []
    for k in range(2, MAX_PARTS + 1):
        labels = np.zeros(frame.shape, np.int32)
        flat = labels.reshape(-1)
        next_label = 1
        for idx, _ in large:
            p = frame.points[idx]
            if len(p) < k:
                continue
            sub = p[rng.choice(len(p), min(len(p), KMEANS_SAMPLE), replace=False)]
            centres = sub[rng.choice(len(sub), k, replace=False)]
            for _ in range(KMEANS_ROUNDS):
                nearest = np.argmin(((sub[:, None] - centres[None]) ** 2).sum(-1), axis=1)
                centres = np.array(
                    [sub[nearest == j].mean(0) if (nearest == j).any() else centres[j] for j in range(k)]
                )
            flat[idx] = next_label + np.argmin(((p[:, None] - centres[None]) ** 2).sum(-1), axis=1)
            next_label += k
        out.append(labels)
    return out


def _distinct(found: _Found, limit: int) -> list[Segment]:
    """The best `limit` proposals, dropping any that repeats a better one: its box overlapping with IoU
    above SAME_IOU and its centre within a quarter of its box's side."""
    x0, y0, x1, y1 = found.box.T
    uv = found.uv
    area = (x1 - x0) * (y1 - y0)
    w = np.clip(np.minimum(x1[:, None], x1[None]) - np.maximum(x0[:, None], x0[None]), 0, None)
    h = np.clip(np.minimum(y1[:, None], y1[None]) - np.maximum(y0[:, None], y0[None]), 0, None)
    iou = w * h / np.maximum(area[:, None] + area[None] - w * h, 1e-9)
    side = np.maximum(x1 - x0, y1 - y0)
    near = np.linalg.norm(uv[:, None] - uv[None], axis=2) < side[:, None] / 4
    same = (iou > SAME_IOU) & near
    score = found.score
    order = np.argsort(-score, kind="stable")
    kept: list[int] = []
    for i in order:
        if not same[i, kept].any():
            kept.append(int(i))
            if len(kept) == limit:
                break
    return [
        Segment(
            float(uv[i, 0]),
            float(uv[i, 1]),
            float(found.distance[i]),
            (float(x0[i]), float(y0[i]), float(x1[i]), float(y1[i])),
            float(score[i]),
            bool(found.part[i]),
        )
        for i in kept
    ]
