"""Training the objectness network: batches, the optimisation on a wall-clock budget, validation on the validation frames' recall, checkpoints and the ONNX export."""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import torch

from index.features.objectness import INPUT, OUTPUT, WINDOW_MM, propose_with
from training.objectness.config import STRIDE, ObjectnessConfig
from training.objectness.model import ObjectnessNet, Scored, centre_loss, regression_loss
from training.objectness.recall import recall
from training.objectness.samples import Frame, load_frames, make_sample, photos_of, shape_renders

log = logging.getLogger(__name__)


def _batches(
    frames: list[Frame],
    shapes: dict[str, np.ndarray],
    cfg: ObjectnessConfig,
    out: queue.Queue,
    stop: threading.Event,
) -> None:
    rng = np.random.default_rng(cfg.seed + 2)
    while not stop.is_set():
        samples = [make_sample(frames, shapes, cfg, rng) for _ in range(cfg.batch)]
        batch = (
            torch.from_numpy(np.stack([s.img.transpose(2, 0, 1) for s in samples]).astype(np.float32)),
            *(
                torch.from_numpy(np.stack([getattr(s, k) for s in samples]))
                for k in ("heat", "weight", "reg", "reg_w")
            ),
        )
        while not stop.is_set():
            try:
                out.put(batch, timeout=1.0)
                break
            except queue.Full:
                pass


def torch_runner(net: ObjectnessNet):
    """`net` as `index.features.objectness.Run`: (1, 3, H, W) float32 -> (5, h, w) with a score in channel 0."""
    scored = Scored(net).eval()

    def run(x: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return scored(torch.from_numpy(x))[0].numpy()

    return run


def validate(net: ObjectnessNet, frames: list[Frame], cfg: ObjectnessConfig, limit: int = 30) -> dict:
    """Recall of the frames' objects (visible >= 0.5) among their proposals, by window and by extent."""
    net.eval()
    run = torch_runner(net)
    # the checkpoint is chosen on the objects it may know: a held-out object's recall is measured after
    # (with every real object held, all are new: the network is chosen on objects it never saw)
    seen = {int(i) for f in frames for i in f.ids}
    if cfg.real_objects != "held":
        seen -= set(cfg.holdout)
    pairs = [
        (propose_with(run, f.rgb, cfg.levels, STRIDE, cfg.reference_px, limit), f.truths(only=seen))
        for f in frames
    ]
    net.head.train()
    return {
        "window": recall(pairs),
        "extent": recall(pairs, by_extent=True),
        "n": sum(len(t) for _, t in pairs),
    }


def score_of(figures: dict, by: str = "window") -> float:
    """What picks the checkpoint: the tight and the loose recall in the top 20, averaged; `by` "window" or
    "extent" (`ObjectnessConfig.select_by`)."""
    w = figures[by]
    return (w["w/16, 6%"]["top20"] + w["w/8, 12%"]["top20"]) / 2


def train(
    data: Path, out: Path, cfg: ObjectnessConfig, cache_dir: Path, threads: int = 2, init: Path | None = None
) -> dict:
    """Trains for `cfg.minutes`, validating every `cfg.val_every` steps; keeps the best checkpoint
    (`out/best.pt`) and the last (`out/last.pt`), and a log of the validations (`out/log.jsonl`).
    `init`: a checkpoint whose head this run goes on training (with this run's schedule)."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(threads)
    out.mkdir(parents=True, exist_ok=True)
    train_frames, val_frames = load_frames(data, "train"), load_frames(data, "val")
    log.info("%d train frames, %d val frames", len(train_frames), len(val_frames))
    photos = photos_of(train_frames, np.random.default_rng(cfg.seed + 3)) if cfg.photo_share > 0 else None
    shapes = shape_renders(cfg, cache_dir, photos)
    net = ObjectnessNet(cfg.width)
    if init is not None:
        net.head.load_state_dict(torch.load(init, map_location="cpu", weights_only=False)["head"])
    opt = torch.optim.AdamW(net.head.parameters(), lr=cfg.lr, weight_decay=1e-4)
    q: queue.Queue = queue.Queue(maxsize=3)
    stop = threading.Event()
    producer = threading.Thread(target=_batches, args=(train_frames, shapes, cfg, q, stop), daemon=True)
    producer.start()
    budget = cfg.minutes * 60
    t0, step, best = time.perf_counter(), 0, -1.0
    logf = (out / "log.jsonl").open("a")
    running: list[float] = []
    try:
        while (spent := time.perf_counter() - t0) < budget:
            for g in opt.param_groups:
                g["lr"] = cfg.lr * (
                    cfg.lr_end + (1 - cfg.lr_end) * 0.5 * (1 + math.cos(math.pi * spent / budget))
                )
            x, heat, weight, reg, reg_w = q.get()
            with torch.no_grad():
                d8, d16 = net.features(x)
            y = net.head(d8, d16)
            lc = centre_loss(y[:, 0], heat, weight)
            lr_ = regression_loss(y[:, 1:], reg, reg_w, cfg.scale_weight)
            loss = lc + lr_
            opt.zero_grad()
            loss.backward()
            opt.step()
            step += 1
            running.append(loss.item())
            if step % cfg.val_every == 0 or time.perf_counter() - t0 >= budget:
                figures = validate(net, val_frames, cfg)
                score = score_of(figures, cfg.select_by)
                entry = {
                    "step": step,
                    "minutes": round((time.perf_counter() - t0) / 60, 2),
                    "loss": round(float(np.mean(running)), 4),
                    "score": score,
                    "val": figures,
                }
                running = []
                logf.write(json.dumps(entry) + "\n")
                logf.flush()
                log.info("step %d loss %.4f val score %.4f", step, entry["loss"], score)
                state = {"head": net.head.state_dict(), "cfg": asdict(cfg), "step": step, "val": figures}
                torch.save(state, out / "last.pt")
                if score > best:
                    best = score
                    torch.save(state, out / "best.pt")
    finally:
        stop.set()
        logf.close()
    return torch.load(out / "best.pt", weights_only=False)


def load_checkpoint(path: Path) -> tuple[ObjectnessNet, ObjectnessConfig, dict]:
    state = torch.load(path, map_location="cpu", weights_only=False)
    saved: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in state["cfg"].items()}
    cfg = ObjectnessConfig(**saved)
    net = ObjectnessNet(cfg.width)
    net.head.load_state_dict(state["head"])
    return net.eval(), cfg, state


def export(
    net: ObjectnessNet,
    cfg: ObjectnessConfig,
    out: Path,
    extra: dict[str, str],
    levels: tuple[float, ...] | None = None,
) -> Path:
    """The network as one ONNX file (dynamic H, W) with what `index.features.objectness.ObjectnessNet` reads.
    `levels`: the pyramid `propose` runs by default (default: the one validated in training)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    h, w = torch.export.Dim("h16", min=1, max=256), torch.export.Dim("w16", min=1, max=256)
    torch.onnx.export(
        Scored(net).eval(),
        (torch.zeros(1, 3, 96, 128),),
        str(out),
        input_names=[INPUT],
        output_names=[OUTPUT],
        dynamic_shapes={"rgb": {2: 16 * h, 3: 16 * w}},
        external_data=False,
        dynamo=True,
    )
    model = onnx.load(str(out))
    meta = {
        "kind": "objectness",
        "stride": str(STRIDE),
        "reference_px": f"{cfg.reference_px:g}",
        "window_mm": f"{WINDOW_MM:g}",
        "levels": json.dumps(list(levels or cfg.levels)),
        "input": "rgb (1, 3, H, W) float32 0-255, H and W multiples of 16",
        "output": "cells (1, 5, H/8, W/8): centre score 0-1, dx, dy (cells), log(window_px/reference_px), log(extent_px/reference_px)",
        "config": json.dumps(asdict(cfg)),
        **extra,
    }
    del model.metadata_props[:]
    for k, v in meta.items():
        model.metadata_props.add(key=k, value=v)
    onnx.save(model, str(out))
    return out
