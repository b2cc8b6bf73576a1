"""Leave one video out: a rule chosen on some videos is measured on the one it never saw.

Consecutive frames of a video are near-duplicates, so a threshold chosen on a video's frames and measured on
its other frames measures nothing new. `scripts/calibrate_reject.py --leave-one-video-out` collects each video's
answers once (`evaluation.openset.Answers` keeps each row's scene), then for each video fits the calibration on
the others (`of_videos`) and measures it on that video alone; the figure it reports is the mean over the videos
(`mean_of`), each measured with the calibration it was not chosen on."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from typing import TypeVar

import numpy as np

from evaluation.openset import Answers

T = TypeVar("T")


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
