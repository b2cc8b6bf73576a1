"""Resuming a run: what a checkpoint must carry besides the network, and when it cannot be resumed.

A killed run goes on from its last checkpoint rather than starting over (the target is a model in 60 min
on a shared 2-core machine, where runs get killed). Both trainers store, under the checkpoint's "resume"
key, what their next step depends on besides the network: the optimiser's moments, the wall-clock spent
(the budget and the cosine schedule are fractions of it; bootstrapping starts at a fraction of it too),
the best validation score (so the best-file stays the best of the whole run), the descriptor trainer's
mining bank (rebuilding it would embed all templates again, and differently), and the random states, so
that the batches go on rather than repeat.
Given the same config, the resumed run makes the steps the killed one would have made
(`tests/training/test_train.py`, `test_mask.py`)."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import torch

# settings that change how fast a run goes, not what it computes
FREE = frozenset({"threads"})
#: settings added after runs were made, with the value that computes what those runs computed: a
#: checkpoint without one counts as having it (the local trainer's hard negatives: none)
ADDED = {
    "hard_model": "",
    "hard": 8,
    "hard_pool": 100,
    "mask_jitter": 0.0,
    "outline_weight": 0.0,
    "soft_edges": 0.0,
    "colour_jitter": 0.0,
}


def save_atomic(obj: dict, path: Path) -> None:
    """torch.save through a temporary file: a run killed while writing keeps its previous checkpoint."""
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def config_differences(theirs: dict, ours: dict, prefix: str = "") -> list[tuple[str, object, object]]:
    """The fields (dotted names) where two configs, nested dicts as `asdict` gives them, differ:
    (name, theirs, ours). Tuples equal lists; fields in `FREE` are skipped; a field in `ADDED` that
    `theirs` lacks has its `ADDED` value."""
    out: list[tuple[str, object, object]] = []
    for k in sorted(set(theirs) | set(ours)):
        if k in FREE:
            continue
        a, b = theirs.get(k, ADDED.get(k)), ours.get(k)
        if isinstance(a, dict) and isinstance(b, dict):
            out += config_differences(a, b, f"{prefix}{k}.")
        elif json.dumps(a) != json.dumps(b):
            out.append((prefix + k, a, b))
    return out


def describe(differences: list[tuple[str, object, object]], options: dict[str, str] | None = None) -> str:
    """`config_differences` as one line, "name (--option): was A, now B; ...": options maps fields to the
    command's options."""
    options = options or {}
    return "; ".join(
        f"{k}{f' ({options[k]})' if k in options else ''}: was {json.dumps(a)}, now {json.dumps(b)}"
        for k, a, b in differences
    )


def resume_state(
    ckpt: dict, config: dict, options: dict[str, str] | None = None, name: str = "the checkpoint"
) -> dict:
    """The checkpoint's "resume" state, once it is known to be a run of `config` (asdict of the trainer's
    config, with `minutes` and `max_steps`) with budget left; ValueError (one line, about `name`) when it
    cannot be resumed. options: field -> command option, to name them in the message."""
    if "resume" not in ckpt:
        raise ValueError(f"{name} was written before training could resume (no optimiser state)")
    differ = config_differences(ckpt["config"], config)
    if differ:
        raise ValueError(f"{name} was made with other settings: {describe(differ, options)}")
    spent, step = ckpt["resume"]["elapsed"], ckpt["step"]
    minutes, max_steps = config["minutes"], config.get("max_steps", 0)
    if spent >= minutes * 60 or (max_steps and step >= max_steps):
        of = f" of {max_steps}" if max_steps else ""
        raise ValueError(
            f"{name} ends a run that already used its whole budget "
            f"({spent / 60:.1f} of {minutes:g} min, step {step}{of}): nothing to resume"
        )
    return ckpt["resume"]


def progress_state(opt: torch.optim.Optimizer, t0: float, best: float, rng: np.random.Generator) -> dict:
    """A checkpoint's "resume" state for a trainer of one optimiser and one batch generator: the moments,
    the wall-clock spent since `t0` (a `time.perf_counter`), the best score, the random states."""
    return {
        "optimizer": opt.state_dict(),
        "elapsed": time.perf_counter() - t0,
        "best": best,
        "rng": {"batches": rng.bit_generator.state, "torch": torch.get_rng_state()},
    }


def restore(state: dict, opt: torch.optim.Optimizer, rng: np.random.Generator) -> tuple[float, float]:
    """`progress_state` put back: the optimiser's moments and the random states; returns (elapsed, best)."""
    opt.load_state_dict(state["optimizer"])
    rng.bit_generator.state = state["rng"]["batches"]
    torch.set_rng_state(state["rng"]["torch"])
    return state["elapsed"], state["best"]
