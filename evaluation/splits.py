"""Which frames of a dataset a model's training chose for each split, as its ONNX metadata records them
(written by `posedesc export`): the validation frames that choose, the test frames that report, and the
frames it was never trained on."""

from __future__ import annotations

import json
from pathlib import Path


def heldout_frames(meta: dict[str, str], dataset: Path, scene: int) -> list[int] | None:
    """The frames of `dataset`'s scene a model was not trained on, from its `heldout_frames` metadata
    ({"<dataset folder>/<scene>": [frame ids]}, written by `posedesc export`); None when it has none."""
    try:
        heldout = json.loads(meta.get("heldout_frames", "{}"))
    except json.JSONDecodeError:
        return None
    frames = heldout.get(f"{dataset.resolve().name}/{scene:06d}")
    return sorted(int(f) for f in frames) if frames else None


def split_frames(meta: dict[str, str], dataset: Path, scene: int, split: str) -> list[int] | None:
    """The frames of `dataset`'s scene in the model's `split` ("train", "val", "test"), from its
    `split_frames` metadata ({"<dataset folder>/<scene>": {"train": [...], "val": [...], "test": [...]}},
    written by `posedesc export`); None when it has none."""
    try:
        splits = json.loads(meta.get("split_frames", "{}"))
    except json.JSONDecodeError:
        return None
    frames = (splits.get(f"{dataset.resolve().name}/{scene:06d}") or {}).get(split)
    return sorted(int(f) for f in frames) if frames else None
