"""OpenCV's LineMOD (`cv2.linemod`) as a whole-frame detector, beside the service's detector in `posedesc
evaluate --protocol detect`: the same frames, the same template renders, the same scales.

Templates are the service's template renders (`index.templates.render.Renderer`: 64 px, a 200 mm window at 400 mm),
one LineMOD class each, with the feature counts and padding of the patch baseline (`evaluation.baselines.linemod`,
whose docstring has the reasons). A template shows an object's `window_mm` across `size` px; in a frame an
object `d` mm away spans f * window_mm / d px, so the frame is matched at a pyramid of window sizes
(`window_sizes`: the service detector's, from 64 px up to the frame's short side, 2^(1/3) apart), each
scale resized so that the window is `size` px, and a match at window w px puts the object at
d = f * window_mm / w along the ray through the template's centre. Every match is a candidate (its
similarity at least `CANDIDATE_SIMILARITY`); candidates of every scale, object and template are thinned by
greedy non-maximum suppression on their boxes (`NMS_IOU`, whatever the object: one object stands at one
place), most similar first, and the `max_detections` best are the detections. A detection's box is the
template's silhouette box where it matched; its pose the template's view along the ray at that distance.

With depth (rgbd, depth), LineMOD's normals see each scale's depth shifted so that a pixel's width at the
scale's distance is what LineMOD's fixed focal length assumes (`LineModIndex.depth_ref_mm`)."""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from evaluation.baselines.linemod import COLOUR_FEATURES, DEPTH_FEATURES, PAD, LineModIndex
from evaluation.detect.score import FrameKey, Hit
from index.geometry.pose import View, view_to_pose
from index.templates.render import Templates

SMALLEST_WINDOW_PX = 64.0  # the service detector's smallest window (an object at f * 200 / 64 ~ 1.8 m)
WINDOW_STEP = 2 ** (1 / 3)  # the service detector's step between windows
#: a LineMOD match less similar (percent) is no candidate. On LM-O validation frames 224, 243, 248 (the
#: 7 objects, 21,698 templates) the best match on each target scored 93-95 and after suppression every
#: frame still had 10 candidates above 97, so nothing below 90 is ever among the 10 reported; at 80 a
#: frame gave 1.5 M matches (5 s), at 70 5.2 M
CANDIDATE_SIMILARITY = 90.0
#: two candidates whose boxes overlap more than this are one detection (the more similar one): the
#: service detector's (`service.detection.NMS_IOU`), two boxes that could both count as one instance
NMS_IOU = 0.5
FEATURES = (COLOUR_FEATURES, DEPTH_FEATURES)
MARGIN = 32  # px of zeros round each scaled frame: a template may match an object the frame's edge cuts
#: scaled frames are padded to multiples of this: sides divisible by LineMOD's T at every level, rows a
#: multiple of 16 bytes (its SIMD spreading crashes otherwise: `evaluation.baselines.linemod`)
ALIGN = 64


def window_sizes(
    short_side: float, smallest: float = SMALLEST_WINDOW_PX, step: float = WINDOW_STEP
) -> np.ndarray:
    """Window sides (px) from `smallest` up to the frame's short side, `step` apart."""
    if short_side < smallest:
        return np.array([float(smallest)])
    n = int(np.floor(np.log(short_side / smallest) / np.log(step) + 1e-9)) + 1
    return smallest * step ** np.arange(n)


class LineModFrames:
    """LineMOD templates of several objects, and their detection in whole frames."""

    def __init__(
        self,
        modality: str,
        window_mm: float,
        size: int = 64,
        threshold: float = CANDIDATE_SIMILARITY,
        features: tuple[int, int] = FEATURES,
    ):
        self.modality, self.window_mm, self.size = modality, window_mm, size
        self.index = LineModIndex(modality, window_mm, size, threshold, features)
        self.obj_ids: list[int] = []
        self.views: list[View] = []
        self.boxes: list[tuple[int, int, int, int]] = []  # silhouette box in the padded template image

    def __len__(self) -> int:
        return len(self.views) - self.index.skipped

    def add(self, obj_id: int, templates: Templates, progress: Callable[[int], object] | None = None) -> None:
        """One object's rendered templates (`index.templates.render.Renderer.render`)."""
        mask = templates.depth > 0
        n = len(templates.views)
        self.index.add(
            np.full(n, obj_id),
            templates.rgb if self.modality in ("rgb", "rgbd") else None,
            templates.depth if self.modality in ("depth", "rgbd") else None,
            mask,
            np.array([v.distance for v in templates.views]),
            progress=progress,
        )
        offset = (PAD - self.size) // 2
        for m in mask:
            ys, xs = np.nonzero(m)
            box = (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1) if len(xs) else (0, 0, 0, 0)
            self.boxes.append(tuple(int(c) + offset for c in box))  # type: ignore[arg-type]  # 4 ints
        self.obj_ids += [obj_id] * n
        self.views += list(templates.views)

    def _sources(self, rgb: np.ndarray | None, depth: np.ndarray | None, scale: float, nominal_mm: float):
        """A frame at one scale as LineMOD takes it: resized, a margin round it, sides padded to ALIGN."""
        h, w = (rgb if rgb is not None else depth).shape[:2]  # type: ignore[union-attr]  # one is given
        sw, sh = max(1, round(w * scale)), max(1, round(h * scale))
        pw, ph = -(-(sw + 2 * MARGIN) // ALIGN) * ALIGN, -(-(sh + 2 * MARGIN) // ALIGN) * ALIGN
        out = []
        if self.modality in ("rgb", "rgbd"):
            canvas = np.zeros((ph, pw, 3), np.uint8)
            small = cv2.resize(rgb[..., ::-1], (sw, sh), interpolation=cv2.INTER_AREA)  # type: ignore[index]
            canvas[MARGIN : MARGIN + sh, MARGIN : MARGIN + sw] = small
            out.append(canvas)
        if self.modality in ("depth", "rgbd"):
            small = cv2.resize(depth, (sw, sh), interpolation=cv2.INTER_NEAREST)  # type: ignore[arg-type]
            shifted = np.where(small > 0, small - nominal_mm + self.index.depth_ref_mm, 0.0)
            canvas = np.zeros((ph, pw), np.uint16)
            canvas[MARGIN : MARGIN + sh, MARGIN : MARGIN + sw] = np.clip(shifted, 0, 65535)
            out.append(canvas)
        return out, sw / w, sh / h

    def candidates(
        self, rgb: np.ndarray | None, depth: np.ndarray | None, K: np.ndarray, windows: np.ndarray
    ) -> dict[str, np.ndarray]:
        """Every match of every scale: template index, similarity (percent), window (px), box and centre
        (frame px). rgb (H, W, 3) RGB uint8; depth (H, W) mm."""
        focal = (K[0, 0] + K[1, 1]) / 2
        rows: list[tuple[int, float, float, float, float, float, float]] = []
        for window in windows:
            nominal = focal * self.window_mm / window
            sources, sx, sy = self._sources(rgb, depth, self.size / window, nominal)
            matches, _ = self.index.detector.match(sources, self.index.threshold)
            for m in matches:
                i, (px, py) = self.index.placed(m.class_id)
                rows.append(
                    (i, m.similarity, window, (m.x - px - MARGIN) / sx, (m.y - py - MARGIN) / sy, sx, sy)
                )
        if not rows:
            return {k: np.zeros((0, *s)) for k, s in (("index", ()), ("similarity", ()), ("window", ()),
                                                       ("box", (4,)), ("centre", (2,)))}  # fmt: skip
        a = np.array(rows)
        idx = a[:, 0].astype(int)
        scale = a[:, 5:7]  # frame to scaled frame, x and y (each side rounds to whole pixels)
        origin = a[:, 3:5]  # where the padded template image's corner (0, 0) lands, frame px, less its corner
        boxes = np.array(self.boxes)[idx].astype(float)
        box = np.concatenate([origin + boxes[:, :2] / scale, origin + boxes[:, 2:] / scale], axis=1)
        centre = origin + (PAD / 2) / scale - 0.5  # pixel-centre coordinates, as K projects
        return {"index": idx, "similarity": a[:, 1], "window": a[:, 2], "box": box, "centre": centre}

    def detect(
        self,
        frame: FrameKey,
        rgb: np.ndarray | None,
        depth: np.ndarray | None,
        K: np.ndarray,
        windows: np.ndarray,
        max_detections: int = 10,
    ) -> list[Hit]:
        """The frame's detections, most similar first; score = similarity / 100."""
        c = candidates = self.candidates(rgb, depth, K, windows)
        keep = suppress(candidates["box"], candidates["similarity"], NMS_IOU, max_detections)
        focal = (K[0, 0] + K[1, 1]) / 2
        K_inv = np.linalg.inv(K)
        hits = []
        for j in keep:
            i = int(c["index"][j])
            v = self.views[i]
            u, w = c["centre"][j]
            distance = focal * self.window_mm / c["window"][j]
            R, t = view_to_pose(View(v.azimuth, v.elevation, v.inplane, distance), K_inv @ [u, w, 1.0])
            box = tuple(float(x) for x in c["box"][j])
            hits.append(Hit(frame, self.obj_ids[i], float(c["similarity"][j]) / 100, box, R, t))  # type: ignore[arg-type]
        return hits


def suppress(boxes: np.ndarray, scores: np.ndarray, max_iou: float, n: int) -> list[int]:
    """Greedy non-maximum suppression: up to n indices, best score first, none overlapping a kept one
    by more than `max_iou`. boxes (N, 4) x0, y0, x1, y1."""
    alive = np.ones(len(boxes), bool)
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    keep: list[int] = []
    while len(keep) < n and alive.any():
        j = int(np.flatnonzero(alive)[np.argmax(scores[alive])])
        keep.append(j)
        w = np.clip(np.minimum(boxes[:, 2], boxes[j, 2]) - np.maximum(boxes[:, 0], boxes[j, 0]), 0, None)
        h = np.clip(np.minimum(boxes[:, 3], boxes[j, 3]) - np.maximum(boxes[:, 1], boxes[j, 1]), 0, None)
        inter = w * h
        overlap = inter / np.maximum(area + area[j] - inter, 1e-9)
        alive &= overlap <= max_iou
        alive[j] = False
    return keep
