"""Whole-frame detection scored against BOP ground truth (`posedesc evaluate --protocol detect`).

A detector, whichever it is (the service's `service.detection.detect`, OpenCV's LineMOD over a frame
pyramid: `evaluation.baselines.linemod_frames`), is reduced to `Hit`s: a frame, an object, a score, a box and,
when it gives one, a pose. `match` pairs them with the annotated instances (`Truth`) the PASCAL VOC / COCO
way, greedy by score:

- a hit is right (a true positive) when it names the instance's object and its box overlaps the
  instance's visible box or its whole box (BOP `scene_gt_info` `bbox_visib` / `bbox_obj`) with
  IoU >= `IOU`, and the instance is not matched yet; among several such, the one it overlaps most;
- an instance less than `MIN_VISIB` visible is neither a target nor an error: a hit that overlaps one
  (and no unmatched target) is ignored, as COCO ignores "crowd" regions; any number of hits may;
- any other hit is a false positive, a second hit on a matched instance included.

`scores` then gives recall, precision, AP50 and the pose figures, over all objects and per object.
AP is the area under the precision-recall curve of one ranking (every hit of every frame and object,
ignored hits left out) with VOC 2010+'s all-point interpolation: precision at each recall made the
largest precision at any recall as large or larger, summed over the recall steps (COCO samples the same
curve at 101 recalls instead)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from index.data.bop import Instance
from index.geometry.boxes import iou
from index.geometry.pose_error import rotation_error
from index.geometry.symmetry import Symmetry

IOU = 0.5  # least box overlap of a right detection (the "50" of AP50)
MIN_VISIB = 0.5  # least visible fraction of a target; below it an instance is neither target nor error
ROTATION_OK_DEG = 20.0  # a right detection's pose counts as found when its 3-D rotation error is below this

Box = tuple[float, float, float, float]  # x0, y0, x1, y1 px
FrameKey = tuple[int, int]  # scene id, frame id

# what `match` made of each hit
TRUE, FALSE, IGNORED = "tp", "fp", "ignored"


@dataclass(frozen=True)
class Hit:
    """One detection, whatever found it. R (3, 3), t (3,) mm: its pose in the camera (BOP's cam_R_m2c,
    cam_t_m2c), None when the detector gives none."""

    frame: FrameKey
    obj_id: int
    score: float
    box: Box
    R: np.ndarray | None = None
    t: np.ndarray | None = None


@dataclass(frozen=True)
class Truth:
    """One annotated instance: its visible and whole boxes, visible fraction and pose."""

    frame: FrameKey
    obj_id: int
    box_visib: Box
    box_obj: Box
    visib: float
    R: np.ndarray
    t: np.ndarray

    @property
    def target(self) -> bool:
        return self.visib >= MIN_VISIB

    @classmethod
    def of(cls, inst: Instance) -> Truth:
        """From a BOP instance; it needs `scene_gt_info.json` (the boxes)."""
        if inst.bbox_visib is None or inst.bbox_obj is None:
            raise ValueError(
                f"scene {inst.scene_id} frame {inst.frame_id}: no bbox_visib / bbox_obj "
                "(the detect protocol needs the scene's scene_gt_info.json)"
            )
        return cls(
            (inst.scene_id, inst.frame_id),
            inst.obj_id,
            xywh_box(inst.bbox_visib),
            xywh_box(inst.bbox_obj),
            inst.visib_fract,
            inst.R,
            inst.t,
        )


def xywh_box(b: Sequence[float]) -> Box:
    """BOP's [x, y, w, h] as (x0, y0, x1, y1)."""
    return (float(b[0]), float(b[1]), float(b[0] + b[2]), float(b[1] + b[3]))


@dataclass(frozen=True)
class Matched:
    """`match`'s outcome: hits most confident first, what each was (TRUE, FALSE, IGNORED), for each
    true one the index in `truths` of the instance it found (-1 otherwise), and which false ones are
    duplicates (`duplicate`: the right object on an instance a more confident hit already found)."""

    hits: list[Hit]
    outcome: list[str]
    truth_of: list[int]
    truths: Sequence[Truth]
    duplicate: list[bool] = field(default_factory=list)


def match(hits: Sequence[Hit], truths: Sequence[Truth]) -> Matched:
    """Greedy matching by score (the module's docstring). Ties keep the hits' order."""
    ranked = sorted(hits, key=lambda h: -h.score)
    by_key: dict[tuple[FrameKey, int], list[int]] = {}
    for j, tr in enumerate(truths):
        by_key.setdefault((tr.frame, tr.obj_id), []).append(j)
    taken = np.zeros(len(truths), bool)
    outcome, truth_of, duplicate = [], [], []
    for h in ranked:
        best, best_iou, ignored, again = -1, IOU, False, False
        for j in by_key.get((h.frame, h.obj_id), []):
            tr = truths[j]
            overlap = max(iou(h.box, tr.box_visib), iou(h.box, tr.box_obj))
            if overlap < IOU:
                continue
            if not tr.target:
                ignored = True
            elif not taken[j] and overlap >= best_iou:
                best, best_iou = j, overlap
            elif taken[j]:
                again = True
        if best >= 0:
            taken[best] = True
        outcome.append(TRUE if best >= 0 else IGNORED if ignored else FALSE)
        truth_of.append(best)
        duplicate.append(best < 0 and not ignored and again)
    return Matched(ranked, outcome, truth_of, truths, duplicate)


def average_precision(right: Sequence[bool], n_targets: int) -> float:
    """All-point interpolated AP (VOC 2010+) of a ranking, most confident first: `right` says which hits
    are true positives; `n_targets` is how many there are to find."""
    if n_targets == 0:
        return float("nan")
    right_ = np.asarray(right, bool)
    if not len(right_):
        return 0.0
    tp = np.cumsum(right_)
    precision = tp / np.arange(1, len(right_) + 1)
    recall = tp / n_targets
    # the precision envelope: at each recall, the best precision at that recall or beyond
    envelope = np.maximum.accumulate(precision[::-1])[::-1]
    steps = np.diff(np.concatenate([[0.0], recall]))
    return float(np.sum(steps * envelope))


def _figures(m: Matched, hits: list[int], targets: list[int], symmetries: Mapping[int, Symmetry]) -> dict:
    """The figures of the hits (indices into `m.hits`) and targets (indices into `m.truths`) of a subset."""
    kept = [i for i in hits if m.outcome[i] != IGNORED]
    right = [m.outcome[i] == TRUE for i in kept]
    tp, n = int(sum(right)), len(targets)
    rotation_ok, distance = 0, []
    for i in kept:
        if m.outcome[i] != TRUE:
            continue
        h, tr = m.hits[i], m.truths[m.truth_of[i]]
        if h.R is not None and rotation_error(h.R, tr.R, symmetries.get(tr.obj_id, "none")) < ROTATION_OK_DEG:
            rotation_ok += 1
        if h.t is not None:
            true = float(np.linalg.norm(tr.t))
            distance.append(abs(float(np.linalg.norm(h.t)) - true) / true)
    return {
        "targets": n,
        "hits": len(kept),
        "true_positives": tp,
        "false_positives": len(kept) - tp,
        "duplicates": sum(m.duplicate[i] for i in kept) if m.duplicate else None,  # of the false positives
        "ignored": len(hits) - len(kept),
        "recall": tp / n if n else None,
        "precision": tp / len(kept) if kept else None,
        "ap50": _finite(average_precision(right, n)),
        "rotation_within_20": rotation_ok / n if n else None,
        "median_relative_distance_error": float(np.median(distance)) if distance else None,
    }


def _finite(x: float) -> float | None:
    return None if np.isnan(x) else x


def scores(m: Matched, symmetries: Mapping[int, Symmetry] | None = None) -> dict:
    """Recall, precision, AP50 (one ranking), the share of targets found with a 3-D rotation error below
    `ROTATION_OK_DEG` (symmetry-aware: `index.geometry.pose_error.rotation_error`), the median relative distance
    error |‖t‖ - ‖t_gt‖| / ‖t_gt‖ of right hits; over all objects ("all") and per object id ("per_object").
    `symmetries`: each object's (`index.geometry.symmetry`); none: asymmetric."""
    sym = symmetries or {}
    targets = [j for j, tr in enumerate(m.truths) if tr.target]
    out = {"all": _figures(m, list(range(len(m.hits))), targets, sym), "per_object": {}}
    for o in sorted({tr.obj_id for tr in m.truths} | {h.obj_id for h in m.hits}):
        hits = [i for i, h in enumerate(m.hits) if h.obj_id == o]
        out["per_object"][str(o)] = _figures(m, hits, [j for j in targets if m.truths[j].obj_id == o], sym)
    return out
