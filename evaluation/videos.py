"""Leave one video out: a rule chosen on some videos is measured on the one it never saw.

Consecutive frames of a video are near-duplicates, so a threshold chosen on a video's frames and measured on
its other frames measures nothing new. `scripts/calibrate_reject.py --leave-one-video-out` collects each video's
answers once (`evaluation.openset.Answers` keeps each row's scene), then for each video fits the calibration on
the others (`of_videos`) and measures it on that video alone; the figure it reports is the mean over the videos
(`mean_of`), each measured with the calibration it was not chosen on."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import Any, TypeVar

import numpy as np

from evaluation.calibration import auc
from evaluation.openset import Answers, calibrate, calibrate_term, decision_threshold, kinds_of, measure
from service.rejection import Calibration

T = TypeVar("T")

#: the statistics `weights_by_video` chooses among: the lead's weight (None: the distance alone) and the fit
#: term's weight (0: none)
LEADS = (None, 0.25, 0.5, 1.0, 2.0)
FITS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.6)


def of_videos(a: Answers, scenes: Collection[int]) -> Answers:
    """The rows of `a` from these scenes (videos) only."""
    if len(a.scene) != len(a.obj):
        raise ValueError("these answers do not say their scenes (collected before scenes were kept)")
    keep = np.isin(np.array(a.scene, int), list(scenes))

    def rows(xs: list[T]) -> list[T]:
        return [x for x, k in zip(xs, keep, strict=True) if k]

    def per_kind(by: dict[str, list[T]]) -> dict[str, list[T]]:
        return {kind: rows(xs) for kind, xs in by.items()}

    return Answers(
        obj=rows(a.obj),
        registered=rows(a.registered),
        run=rows(a.run),
        frame=rows(a.frame),
        scene=rows(a.scene),
        objects=per_kind(a.objects),
        distances=per_kind(a.distances),
        settings=a.settings,
        data=a.data,
        colours=per_kind(a.colours),
        unexplained=per_kind(a.unexplained),
    )


#: the figures of `evaluation.openset.measure`'s blocks that are shares (averaged over videos) and counts
#: (summed); medians and curves are kept per video only
SHARES = ("recognised", "rejected_unknown", "rejected_registered", "rejected_right", "rejected_wrong")
COUNTS = ("runs", "n", "n_registered", "n_unknown")


def mean_of(blocks: Mapping[int, dict]) -> dict:
    """One `measure` block from one per video (scene -> block): each share the mean over the videos that have
    it (None where none does), each count summed; `videos` says which were measured."""
    out: dict = {"per_unregistered_object": {}, "by_registered": {}, "videos": sorted(blocks)}
    for part in ("per_unregistered_object", "by_registered"):
        keys = sorted({k for b in blocks.values() for k in b[part]}, key=int)
        for key in keys:
            rows = [b[part][key] for b in blocks.values() if key in b[part]]
            merged = {c: sum(r[c] for r in rows) for c in COUNTS if any(c in r for r in rows)}
            for s in SHARES:
                have = [r[s] for r in rows if r.get(s) is not None]
                merged[s] = round(float(np.mean(have)), 4) if have else None
            out[part][key] = merged
    return out


def calibrated(a: Answers, kind: str, lead: float | None, fit: float, rule: tuple[str, float]) -> Calibration:
    """The statistic of this lead weight (None: the distance) and fit term weight, its thresholds by `rule`."""
    stat = Calibration(
        kind, 0.0, 0.0, 0.0, statistic="distance" if lead is None else "lead", weight=lead or 0.0
    )
    cal, _ = calibrate(a, stat, rule, "val")
    return calibrate_term(a, cal, "fit", fit, rule)[0] if fit else cal


def separation(a: Answers, kind: str, cal: Calibration) -> float:
    """The area under the ROC curve of unregistered objects' best answers against registered ones'."""
    right, wrong, unknown = kinds_of(a, kind, cal)
    return auc(unknown, np.concatenate([right, wrong]))


def weights_by_video(
    a: Answers,
    kind: str,
    rule: tuple[str, float],
    sets: list[list[int]],
    fold: int,
    shipped: tuple[float | None, float],
) -> dict[str, Any]:
    """The statistic itself chosen leave one video out: for each video, every (lead, fit) of `LEADS` x `FITS`
    calibrated by `rule` on the other videos, the one separating best there (AUC; ties: `shipped`, then the
    first) measured on the video left out (`measure`, the set with the fewest objects registered); and the
    mean over the videos of the chosen ones and of `shipped` (lead, fit) held fixed."""
    videos = sorted(set(a.scene))
    out: dict[str, dict[str, Any]] = {}
    for video in videos:
        train, test = of_videos(a, [v for v in videos if v != video]), of_videos(a, [video])
        tried: list[dict[str, Any]] = []
        for lead in LEADS:
            for fit in FITS:
                cal = calibrated(train, kind, lead, fit, rule)
                held = measure(test, cal, sets, fold)["by_registered"]
                held = held[min(held, key=int)]
                tried.append({
                    "lead": lead, "fit": fit, "auc_others": round(separation(train, kind, cal), 4),
                    "threshold": decision_threshold(cal), "rejected_unknown": held["rejected_unknown"],
                    "rejected_registered": held["rejected_registered"], "rejected_right": held["rejected_right"],
                })  # fmt: skip
        best = max(tried, key=lambda r: (r["auc_others"], (r["lead"], r["fit"]) == shipped))
        fixed = next(r for r in tried if (r["lead"], r["fit"]) == shipped)
        out[str(video)] = {"chosen": best, "shipped": fixed, "tried": tried}

    def mean(which: str, share: str) -> float:
        return round(float(np.mean([out[str(v)][which][share] for v in videos])), 4)

    return {
        "videos": out,
        "mean": {
            w: {s: mean(w, s) for s in ("rejected_unknown", "rejected_registered")}
            for w in ("chosen", "shipped")
        },
    }
