"""Whole-frame object proposals: where an object's origin projects and how large its window is there.

A small class-agnostic network (trained by `training/objectness/`, shipped as
`models/posedesc-objectness.onnx`) maps a frame to a grid of cells, one every `stride` px, each with a
centre score, the centre's offset from the cell and the log sizes of two things around the centre: the
object's 200 mm window (`window_px = fx * 200 / distance`, what the verifier crops) and its projected
diameter (`extent_px = fx * diameter / distance`, which needs no knowledge of which object it is). The head
only knows windows of about `reference_px` (a factor of 1.6 either way), so the frame is run at a pyramid of
scales (`levels`, half-octave steps) and each object is found at the levels where its window fits; peaks of
every level are merged by a non-maximum suppression across levels.

Conventions: pixel coordinates are OpenCV's (pixel centres at integers); a level is the frame resized to
`round(W * s) x round(H * s)` with INTER_AREA, its pixel x at frame pixel `(x + 0.5) / sx - 0.5`, and cell
(i, j) of a level sits at level pixel `(stride * j + (stride - 1) / 2, stride * i + (stride - 1) / 2)`.
No torch here: the service imports it."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
import onnx
import onnxruntime as ort

OBJECTNESS_FILE = "posedesc-objectness.onnx"  # its file in a models dir, beside the descriptor models


INPUT = "rgb"  # (1, 3, H, W) float32 pixel values 0-255, H and W multiples of `PAD_TO`


OUTPUT = "cells"  # (1, 5, H / stride, W / stride): score 0-1, dx, dy (cells), log window, log extent


PAD_TO = 16  # the deepest map is at stride 16: a level is padded (black, bottom and right) to a multiple


WINDOW_MM = 200.0  # the window that `window_px` spans: the shipped descriptors' window


# Peaks under this score are dropped before the suppression. An all-black frame's peaks score 0.04-0.055
# (6 are left over 0.05); on the validation frames the 20th proposal scores 0.16-0.26, and 0.06 already
# lost a hit (w/16, 6 %) from the top 30.
MIN_SCORE = 0.05


MAX_PEAKS_PER_LEVEL = 200


# Two proposals are one object when their centres are within this share of the larger window and their
# windows within this ratio: the same object found at two levels lands within a few px and ~10 %, and two
# LM-O objects standing side by side are half a window or more apart. Validation frames (the shipped model,
# 9 levels): 0.15, 0.2 and 0.25 gave 46 % within w/16 and 6 % in the top 20 alike, 83-82 % within w/8, 12 %.
SUPPRESS_RADIUS = 0.2


SUPPRESS_RATIO = 1.5


@dataclass(frozen=True)
class Peak:
    """A place where the network sees an object's origin. Pixel units of the frame given to `propose`."""

    u: float
    v: float
    window_px: float  # the object's 200 mm window at its distance: fx * 200 / distance
    score: float  # the network's centre score, 0..1
    extent_px: float  # its projected diameter: fx * diameter / distance (distance = fx * diameter / this)


class Seen(Protocol):
    """A colour proposal as the objectness network gives it (`Peak`, or any object alike): the centre
    (px), the side of the object's model window there (px) and its score."""

    @property
    def u(self) -> float: ...
    @property
    def v(self) -> float: ...
    @property
    def window_px(self) -> float: ...
    @property
    def score(self) -> float: ...


#: colour proposals of a frame: (rgb (H, W, 3) uint8, limit) -> the best `limit`, best first
Colour = Callable[[np.ndarray, int], Sequence[Seen]]


Run = Callable[[np.ndarray], np.ndarray]  # (1, 3, H, W) float32 -> (5, H / stride, W / stride)


class ObjectnessNet:
    """The ONNX proposal network with its metadata. Thread-safe (onnxruntime sessions are)."""

    def __init__(self, path: str | Path, threads: int = 1):
        self.path = Path(path)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads, opts.inter_op_num_threads = threads, 1
        try:
            model = onnx.load(str(self.path))
            self.session = ort.InferenceSession(
                model.SerializeToString(), opts, providers=["CPUExecutionProvider"]
            )
        except Exception as e:
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise ValueError(f"cannot load ONNX model {self.path}: {first}") from None
        self.metadata = {p.key: p.value for p in model.metadata_props}
        if self.metadata.get("kind") != "objectness":
            raise ValueError(f"not an objectness model: {self.path} (metadata kind is not 'objectness')")
        self.stride = int(self.metadata["stride"])
        self.reference_px = float(self.metadata["reference_px"])
        self.levels = tuple(float(s) for s in json.loads(self.metadata["levels"]))

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.session.run([OUTPUT], {INPUT: x})[0][0]


def level_input(rgb: np.ndarray, scale: float) -> tuple[np.ndarray, float, float]:
    """The frame resized by `scale`, padded to `PAD_TO`, as the network's input, and the scales that
    were really applied (sx, sy). Shape: (H, W, 3) uint8 -> (1, 3, H', W') float32."""
    h, w = rgb.shape[:2]
    lw, lh = max(1, round(w * scale)), max(1, round(h * scale))
    img = cv2.resize(rgb, (lw, lh), interpolation=cv2.INTER_AREA) if (lw, lh) != (w, h) else rgb
    x = np.zeros((1, 3, -(-lh // PAD_TO) * PAD_TO, -(-lw // PAD_TO) * PAD_TO), np.float32)
    x[0, :, :lh, :lw] = img.transpose(2, 0, 1)
    return x, lw / w, lh / h


def decode(
    cells: np.ndarray, sx: float, sy: float, stride: int, reference_px: float, min_score: float = MIN_SCORE
) -> list[Peak]:
    """The peaks (3 x 3 local maxima over `min_score`) of one level's output, in frame pixels."""
    score = np.ascontiguousarray(cells[0], np.float32)
    peaks = (score >= cv2.dilate(score, np.ones((3, 3), np.uint8))) & (score >= min_score)
    i, j = np.nonzero(peaks)
    order = np.argsort(-score[i, j])[:MAX_PEAKS_PER_LEVEL]
    i, j = i[order], j[order]
    half = (stride - 1) / 2
    u = (stride * (j + cells[1, i, j]) + half + 0.5) / sx - 0.5
    v = (stride * (i + cells[2, i, j]) + half + 0.5) / sy - 0.5
    s = (sx + sy) / 2
    window = reference_px * np.exp(cells[3, i, j]) / s
    extent = reference_px * np.exp(cells[4, i, j]) / s
    return [
        Peak(float(a), float(b), float(c), float(d), float(e))
        for a, b, c, d, e in zip(u, v, window, score[i, j], extent, strict=True)
    ]


def suppress(proposals: Sequence[Peak], limit: int) -> list[Peak]:
    """One proposal per object, best first: each peak joins the best one before it that is the same object
    (`SUPPRESS_RADIUS`, `SUPPRESS_RATIO`) or leads a new one. A proposal keeps its leader's score and the
    score-weighted mean of its members' centres and (log) sizes: one object seen at several levels gives
    several estimates, and their mean is nearer the truth than the best-scored one (on the validation
    frames, +5 points of objects within w/16 and 6 %)."""
    groups: list[list[Peak]] = []
    for p in sorted(proposals, key=lambda p: -p.score):
        for g in groups:
            k = g[0]
            big, small = max(p.window_px, k.window_px), min(p.window_px, k.window_px)
            if np.hypot(p.u - k.u, p.v - k.v) < SUPPRESS_RADIUS * big and big < SUPPRESS_RATIO * small:
                g.append(p)
                break
        else:
            if len(groups) < limit:
                groups.append([p])
    return [_fused(g) for g in groups]


def _fused(group: Sequence[Peak]) -> Peak:
    if len(group) == 1:
        return group[0]
    w = np.array([p.score for p in group], np.float64)
    w /= w.sum()
    u, v, lw, le = (
        np.array([[p.u, p.v, np.log(p.window_px), np.log(p.extent_px)] for p in group]).T @ w
    ).tolist()
    return Peak(u, v, float(np.exp(lw)), group[0].score, float(np.exp(le)))


def propose_with(
    run: Run,
    rgb: np.ndarray,
    levels: Sequence[float],
    stride: int,
    reference_px: float,
    limit: int = 30,
    min_score: float = MIN_SCORE,
) -> list[Peak]:
    """`propose` with any runner of the network (training validates its torch module through this)."""
    found: list[Peak] = []
    for s in levels:
        x, sx, sy = level_input(rgb, s)
        if min(x.shape[2:]) < PAD_TO:
            continue  # a level smaller than one deepest cell sees nothing
        found += decode(run(x), sx, sy, stride, reference_px, min_score)
    return suppress(found, limit)


def propose(
    net: ObjectnessNet, rgb: np.ndarray, limit: int = 30, levels: Sequence[float] | None = None
) -> list[Peak]:
    """Up to `limit` proposals in a frame of any size, best first. Shape: rgb (H, W, 3) uint8."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"propose takes an (H, W, 3) uint8 RGB frame, not {rgb.shape} {rgb.dtype}")
    if limit < 1:
        raise ValueError(f"limit must be 1 or more, not {limit}")
    return propose_with(net, rgb, levels or net.levels, net.stride, net.reference_px, limit)
