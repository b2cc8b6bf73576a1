"""What one evaluation measures (`posedesc evaluate`'s options): the data, the model, the protocol, the
methods, and the service's settings it overrides."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

METHODS = ("ours", "hog", "linemod")


@dataclass
class Config:
    dataset: Path
    model: Path
    modality: str
    scene: int = 2
    min_visib: float = 0.5
    protocol: str = "service"
    methods: tuple[str, ...] = METHODS
    unseen: tuple[int, ...] = ()
    frames: Sequence[int] | None = None  # None: every frame of the scene
    objects: Sequence[int] | None = None  # None: every object of the dataset
    #: in-plane variants of every template, degrees apart: full protocol (default 20°); service protocol:
    #: the service's setting (None: the settings' own, by default the model's metadata)
    inplane_step: float | None = None
    inplane_max: float | None = None  # service protocol: the service's setting (None: the settings')
    query_turns: int | None = None  # service protocol: the service's setting (None: the settings')
    #: True: synthetic scenes; None: only when the dataset lacks the images (the service protocol renders
    #: just the depth where only depth is missing: `evaluation.paper.samples.served_data`)
    synthetic: bool | None = None
    linemod_threshold: float = 50.0
    #: service protocol: each frame sent black outside the instance's ground-truth visible mask (the
    #: clutter-free bound, `evaluation/masks.py`); colour only
    oracle_mask: bool = False
    #: service protocol: every frame sent again at these camera rolls, degrees (`evaluation.rolls`);
    #: empty: each frame once, as it is
    rolls: tuple[float, ...] = ()
    #: service protocol: a second BOP dataset whose every object is registered too and never queried (an
    #: answer naming one is wrong): how much registering other objects takes from these ones
    distractors: Path | None = None
    #: service protocol: each instance sent as the patch a user would cut from its frame, through its object's
    #: registered window, with that window and the distance, no camera (`evaluation.queries.patch_query`)
    patches: bool = False
    seed: int = 0


def check_methods(methods: Sequence[str]) -> None:
    if unknown := set(methods) - set(METHODS):
        raise ValueError(f"unknown methods {sorted(unknown)}; use some of {', '.join(METHODS)}")
