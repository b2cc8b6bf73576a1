"""Training loop: the paper's batches and cost, Adam, a wall-clock budget, a checkpoint per epoch.

The paper's schedule (SGD + Nesterov, ~1,300 epochs, two bootstrapping rounds) takes days on a CPU; here
Adam with a cosine decay over a fixed wall-clock budget, bootstrapping switched on after `bootstrap_after`
of it. Batches are made by a producer thread while the network trains on the previous one.

A run can be resumed from its last checkpoint (`train(..., resume=True)`): the checkpoint carries, under
"resume", what the next step depends on besides the network (optimiser, time spent, best score, mining
bank, random states), so the resumed run makes the steps the killed one would have made.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from training.batches import Batch, BatchBuilder, bootstrap_triplets
from training.data import DataConfig, TrainingData
from training.losses import DescriptorLoss
from training.mining import TemplateBank, mine
from training.model import DescriptorNet, NetConfig
from training.resume import resume_state, save_atomic

log = logging.getLogger(__name__)


@dataclass
class TrainConfig:
    modality: str = "rgb"
    arch: str = "paper"  # "paper" (the baseline) or "trunk" (frozen pretrained MobileNetV2 stages + head)
    descriptor_dim: int = 16  # the paper's default; 32 in its table
    pool: int = 2  # arch pca: average pooling of the trunk's map
    minutes: float = 25.0  # wall-clock budget for the optimisation (data rendering not included)
    max_steps: int = 0  # stop after this many steps too (0: only the budget); makes --seed runs repeat
    steps_per_epoch: int = 150  # an "epoch" is this many batches: a checkpoint and a validation each
    samples_per_batch: int = 48  # training samples per batch; each brings 3-5 templates
    real_object_share: float = 0.5  # of the samples, the share of the BOP objects (the rest: shapes)
    real_fraction: float = 0.5  # of a BOP object's samples, the share of real patches (where there are)
    lr: float = 1e-3  # Adam; cosine decay to lr * lr_end over the budget
    lr_end: float = 0.05
    # fraction of the budget after which bootstrapping starts: early, since among 170k templates (in-plane
    # variants) random negatives are easy and nearest-neighbour accuracy stayed at chance without it
    bootstrap_after: float = 0.15
    mine: bool = True  # bootstrapping also draws hard templates from all templates (training/mining.py)
    mine_refresh: int = 300  # steps between refreshes of a part of the mining bank's template descriptors
    mine_parts: int = 4  # the bank is refreshed a quarter at a time: 170k templates take ~1 min
    pair_weight: float = 1.0
    margin: float = 0.01  # m of the triplet cost
    weight_decay: float = 1e-6  # lambda, on weights only
    threads: int = 2  # torch intra-op threads: the machine has two cores, shared with a batch producer
    seed: int = 0
    data: DataConfig = field(default_factory=DataConfig)


class BatchProducer:
    """A thread that draws samples, builds batches and the samples' network inputs, ahead of the optimiser.
    A batch's first rows are its samples (`x`, in row order); the rest are templates, whose stems the
    training loop takes from `template_stems`. `rng_state` is the generator's state after the batches `get`
    has handed out (the thread runs ahead of it): a producer started from it makes the batches that follow."""

    def __init__(
        self,
        data: TrainingData,
        cfg: TrainConfig,
        depth: int = 3,
        start: bool = True,
        rng_state: Mapping[str, Any] | None = None,
    ):
        self.data, self.cfg = data, cfg
        self.rng = np.random.default_rng(cfg.seed + 1)
        if rng_state is not None:
            self.rng.bit_generator.state = rng_state
        self.rng_state: Mapping[str, Any] = self.rng.bit_generator.state
        self.builder = BatchBuilder(data.template_R, data.symmetries)
        self.queue: queue.Queue[tuple[Batch, torch.Tensor, Mapping[str, Any]]] = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True, name="batches")
        if start:
            self.thread.start()

    def _objects(self) -> list[int]:
        d, c, rng = self.data, self.cfg, self.rng
        n_real = int(round(c.samples_per_batch * c.real_object_share)) if d.real_objects else 0
        n_real = min(n_real, c.samples_per_batch) if d.n_objects > d.real_objects else c.samples_per_batch
        real = rng.integers(0, d.real_objects, n_real) if d.real_objects else np.zeros(0, int)
        shapes = np.arange(d.real_objects, d.n_objects)
        others = rng.choice(
            shapes, c.samples_per_batch - n_real, replace=len(shapes) < c.samples_per_batch - n_real
        )
        return [int(o) for o in np.concatenate([real, others])]

    def make(self) -> tuple[Batch, torch.Tensor]:
        d, c, rng = self.data, self.cfg, self.rng
        objs = self._objects()
        drawn = [d.draw(o, rng, c.modality, c.real_fraction) for o in objs]
        samples = [s for s, _ in drawn]
        batch = self.builder.make(range(len(objs)), objs, np.stack([R for _, R in drawn]), rng)
        assert list(batch.sample_rows) == list(range(len(objs)))  # samples first, then templates
        x = np.stack([d.sample_input(samples[batch.items[r][2]], c.modality, rng) for r in batch.sample_rows])
        return batch, torch.from_numpy(x)

    def _run(self) -> None:
        while not self._stop.is_set():
            item = (*self.make(), self.rng.bit_generator.state)
            while not self._stop.is_set():
                try:
                    self.queue.put(item, timeout=0.5)
                    break
                except queue.Full:
                    continue

    def get(self) -> tuple[Batch, torch.Tensor]:
        batch, x, self.rng_state = self.queue.get()
        return batch, x

    def stop(self) -> None:
        self._stop.set()


def template_stems(net: DescriptorNet, inputs: np.ndarray, chunk: int = 512) -> np.ndarray:
    """The stems of all templates (their inputs when the stem is nothing), computed once: a frozen trunk
    never changes. Shape: (O, T, C, S, S) -> (O, T, C', S', S') float16."""
    if isinstance(net.stem, torch.nn.Identity):
        return inputs
    flat = inputs.reshape(-1, *inputs.shape[2:])
    with torch.no_grad():
        first = net.stem(torch.from_numpy(flat[:1].astype(np.float32)))
        out = np.zeros((len(flat), *first.shape[1:]), np.float16)
        for i in tqdm(range(0, len(flat), chunk), desc="template stems", unit="chunk", leave=False):
            x = torch.from_numpy(flat[i : i + chunk].astype(np.float32)).contiguous(
                memory_format=torch.channels_last
            )
            out[i : i + chunk] = net.stem(x).numpy()
    return out.reshape(*inputs.shape[:2], *out.shape[1:])


def body_descriptors(net: DescriptorNet, stems: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """Descriptors from stems (eval mode). Shape: (N, C', S', S') -> (N, D)."""
    was = net.training
    net.eval()
    out = []
    with torch.no_grad():
        for i in range(0, len(stems), chunk):
            x = torch.from_numpy(stems[i : i + chunk].astype(np.float32))
            out.append(net.body(x.contiguous(memory_format=torch.channels_last)).numpy())
    net.train(was)
    return np.concatenate(out) if out else np.zeros((0, net.cfg.descriptor_dim), np.float32)


def batch_descriptors(net: DescriptorNet, batch: Batch, x: torch.Tensor, stems: np.ndarray) -> torch.Tensor:
    """Descriptors of every row of a batch: the samples (inputs x) through the whole network, the
    templates from their cached stems through the body; one body call, so BatchNorm sees the batch as
    one. Shape: (B, D)."""
    s = net.stem(x.contiguous(memory_format=torch.channels_last))
    rows = batch.items[len(x) :]
    t = torch.from_numpy(np.stack([stems[it[1], it[2]] for it in rows]).astype(np.float32))
    return net.body(torch.cat([s, t.to(s.dtype)]).contiguous(memory_format=torch.channels_last))


def lr_at(cfg: TrainConfig, progress: float) -> float:
    return cfg.lr * (cfg.lr_end + (1 - cfg.lr_end) * 0.5 * (1 + math.cos(math.pi * min(progress, 1.0))))


def train(
    cfg: TrainConfig,
    data: TrainingData,
    out: Path,
    validate=None,
    command: str = "",
    resume: bool = False,
) -> DescriptorNet:
    """Trains a network on `data`, writing `out/checkpoint.pt` every epoch and `out/log.jsonl`.
    `validate(net, template_f) -> dict` (optional) is called after every epoch and logged; template_f(o)
    gives the descriptors of object o's templates (from their cached stems). `resume`: continue the run
    of `out/checkpoint.pt` (made with the same `cfg`) where it was, appending to its log."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    out.mkdir(parents=True, exist_ok=True)
    net = DescriptorNet(NetConfig(cfg.modality, cfg.descriptor_dim, data.spec.size, cfg.arch))
    # channels_last: the 57x57x16 max-pool after the first convolution runs ~8x faster on this CPU,
    # and a whole step ~1.8x (measured on 285-patch batches).
    net = net.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # torch's stub lacks it
    loss_fn = DescriptorLoss(cfg.margin, cfg.pair_weight, cfg.weight_decay)
    opt = torch.optim.Adam([p for p in net.parameters() if p.requires_grad], lr=cfg.lr)
    # normalised once, here, before the producer thread would do it too
    stems = template_stems(net, data.template_inputs(cfg.modality))
    if stems is not data.template_inputs(cfg.modality):
        data.drop_template_inputs(cfg.modality)  # 2 GB: the trunk's maps are all training needs now
    bank = TemplateBank(stems, cfg.descriptor_dim, cfg.mine_refresh, cfg.mine_parts) if cfg.mine else None

    def embed_stems(a: np.ndarray) -> np.ndarray:
        return body_descriptors(net, a)

    def template_f(o: int) -> np.ndarray:
        return embed_stems(stems[o])

    step, epoch, elapsed = 0, 0, 0.0
    best = -1.0
    batches_rng: Mapping[str, Any] | None = None
    if resume:
        ckpt = torch.load(out / "checkpoint.pt", map_location="cpu", weights_only=False)
        state = resume_state(ckpt, asdict(cfg), name=str(out / "checkpoint.pt"))
        net.load_state_dict(ckpt["net"])
        opt.load_state_dict(state["optimizer"])
        step, epoch, elapsed, best = ckpt["step"], ckpt["epoch"], state["elapsed"], state["best"]
        batches_rng = state["rng"]["batches"]
        torch.set_rng_state(state["rng"]["torch"])
        if bank is not None:
            bank.load_state_dict(state["bank"])
    producer = BatchProducer(data, cfg, rng_state=batches_rng)
    budget = cfg.minutes * 60.0
    t0 = time.monotonic() - elapsed  # the budget and the schedule go on from the time already spent
    logf = (out / "log.jsonl").open("a")
    try:
        done = False
        while not done and not (cfg.max_steps and step >= cfg.max_steps):
            epoch += 1
            sums: dict[str, float] = {}
            bar = tqdm(range(cfg.steps_per_epoch), desc=f"epoch {epoch}", unit="batch", mininterval=10)
            for _ in bar:
                progress = (time.monotonic() - t0) / budget
                if cfg.max_steps:
                    progress = max(progress, step / cfg.max_steps)
                if progress >= 1.0:
                    done = True
                    break
                for g in opt.param_groups:
                    g["lr"] = lr_at(cfg, progress)
                batch, x = producer.get()
                boot = progress >= cfg.bootstrap_after
                if boot and bank is not None:
                    if bank.due(step):
                        bank.refresh(embed_stems, step)
                    batch = mine(bank, net, batch, x)
                net.train()
                f = batch_descriptors(net, batch, x, stems)
                triplets = batch.triplets
                if boot:
                    triplets = np.concatenate([triplets, bootstrap_triplets(batch, f.detach().numpy())])
                    if bank is not None:
                        bank.update(batch, f.detach().numpy())
                loss, terms = loss_fn(net, f, torch.from_numpy(triplets), torch.from_numpy(batch.pairs))
                opt.zero_grad()
                loss.backward()
                opt.step()
                step += 1
                for k, v in terms.items():
                    sums[k] = sums.get(k, 0.0) + v
                sums["n"] = sums.get("n", 0) + 1
                bar.set_postfix(
                    {k: f"{v:.3g}" for k, v in terms.items()} | {"lr": f"{opt.param_groups[0]['lr']:.1e}"},
                    refresh=False,
                )
            bar.close()
            n = max(sums.pop("n", 0), 1)
            record: dict = {
                "epoch": epoch,
                "step": step,
                "minutes": round((time.monotonic() - t0) / 60, 2),
                **{k: v / n for k, v in sums.items()},
            }
            if validate is not None:
                record["val"] = validate(net, template_f)
            ckpt = {
                "net": net.state_dict(),
                "config": asdict(cfg),
                "size": data.spec.size,
                "window_mm": data.spec.window_mm,
                "epoch": epoch,
                "step": step,
                "command": command,
                "val": record.get("val"),
            }
            # the checkpoint chosen on validation frames: 3-D pose error < 20 deg, then recognition
            score = _val_score(record.get("val"))
            if score is not None and score > best:
                best = score
                save_atomic(ckpt, out / "best.pt")
                record["best"] = True
            # best.pt before checkpoint.pt: a run killed between the two redoes this epoch and both
            ckpt["resume"] = {
                "optimizer": opt.state_dict(),
                "elapsed": time.monotonic() - t0,
                "best": best,
                "bank": bank.state_dict() if bank is not None else None,
                "rng": {"batches": producer.rng_state, "torch": torch.get_rng_state()},
            }
            save_atomic(ckpt, out / "checkpoint.pt")
            logf.write(json.dumps(record) + "\n")
            logf.flush()
            log.info("%s", record)
            print(json.dumps(record), flush=True)
    finally:
        producer.stop()
        logf.close()
    return net


def _val_score(val: dict | None) -> float | None:
    if not val:
        return None
    return float(val.get("within_3d_20", 0.0)) + 1e-3 * float(val.get("recognised", 0.0))


def load_checkpoint(run_dir: Path, which: str = "checkpoint") -> tuple[DescriptorNet, dict]:
    """The run's last checkpoint (`checkpoint`) or the one chosen on validation frames (`best`)."""
    ckpt = torch.load(run_dir / f"{which}.pt", map_location="cpu", weights_only=False)
    c = ckpt["config"]
    arch, pool = c.get("arch", "paper"), c.get("pool", 2)
    net = DescriptorNet(NetConfig(c["modality"], c["descriptor_dim"], ckpt["size"], arch, pool), False)
    net.load_state_dict(ckpt["net"])
    return net.eval(), ckpt
