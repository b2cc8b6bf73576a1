"""Which real frames train, which choose (validation) and which report (test).

Frames of one scene are consecutive video frames: neighbours look alike, so a random split would leak.
Each split is made of contiguous blocks of the frame order, and `gap` frames either side of a validation
or test block are kept out of everything ("gap"). The default, 20 % validation and 20 % test in blocks
apart from each other, leaves ~55 % for training. Designs and checkpoints are chosen on "val"; "test" is
looked at once, for the reported figures."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class SplitConfig:
    val: tuple[tuple[float, float], ...] = ((0.20, 0.40),)  # blocks, as fractions of the frame order
    test: tuple[tuple[float, float], ...] = ((0.70, 0.90),)
    gap: int = 2  # frames either side of a val/test block kept out of training (they look alike)


def split_frames(frame_ids: Sequence[int], cfg: SplitConfig = SplitConfig()) -> dict[int, str]:
    """frame id -> "train", "val", "test" or "gap" (next to a val/test block, used by nothing)."""
    ids = sorted(frame_ids)
    n = len(ids)
    out = {f: "train" for f in ids}
    blocks = [(a, b, "val") for a, b in cfg.val] + [(a, b, "test") for a, b in cfg.test]
    for a, b, _ in blocks:  # gaps first, so a block next to another keeps its own frames
        lo, hi = int(round(a * n)), int(round(b * n))
        for k in range(max(0, lo - cfg.gap), min(n, hi + cfg.gap)):
            if out[ids[k]] == "train":
                out[ids[k]] = "gap"
    for a, b, name in blocks:
        lo, hi = int(round(a * n)), int(round(b * n))
        for k in range(lo, hi):
            out[ids[k]] = name
    return out


def frames_of(split: dict[int, str]) -> dict[str, list[int]]:
    """{"train": [...], "val": [...], "test": [...]}: the model's `split_frames` metadata of a scene."""
    return {s: sorted(f for f, v in split.items() if v == s) for s in SPLITS}
