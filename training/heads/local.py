"""Local features for the re-ranking: a copy of the pretrained trunk fine-tuned for what the service asks of it.

The service re-ranks its nearest answers by comparing the query's trunk map with each answer's template,
cell by cell where the object is (`index.features.local.masked_distance`). The ImageNet trunk was never taught which
differences matter there: a cluttered real patch against the right template and against the same object
a half-turn away. This trains a copy of it on exactly that comparison. A query is a training sample
(a synthetic render or a real patch of a training frame, clutter and occluders around it), black outside
the mask head's mask (`query_mask`: as the service blacks it) or outside its true mask; its candidates are
the template nearest its pose (symmetry-aware) and negatives: templates of the same object more than
`far` degrees away (half of them within 70 degrees, the near misses) and templates of other objects. The
score is the service's masked distance (without the coverage term, which no feature changes), and the loss
the cross-entropy of the right template among them at temperature `tau`. `hard_model` adds negatives the
service's first stage would hand the re-ranking: templates near the query in an exported model's
descriptor space (`HardNegatives`; tried, not better on validation frames). The first stages stay
ImageNet's (`frozen_stages`), BatchNorm keeps its statistics, the map's shape is the trunk's, so a store
holds what it held. `posedesc export --onto MODEL.onnx --local RUN` puts it into an exported model
(`training.heads.graft.graft_local`); the descriptor and the mask stay the model's.

Validation: the real instances of the validation frames, cut as the service cuts them (true centre, the
camera's roll), each against its nearest template and fixed negatives drawn the same way: the share whose
right template scores best (`val_top1`)."""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from index.features.local import cell_weights
from index.features.patches import network_input
from training.data import TrainingData
from training.heads.mask import MaskNet
from training.heads.mask import validation_set as mask_validation_set
from training.resume import progress_state, restore, resume_state, save_atomic
from training.similarity import pose_distances, rotations
from training.trunk import Trunk

log = logging.getLogger(__name__)

GRID_DIVISOR = 4  # the trunk's map is a quarter of the patch's side


@dataclass
class LocalConfig:
    minutes: float = 40.0  # wall-clock budget
    max_steps: int = 0  # also stop after this many steps (0: only the budget)
    batch: int = 16  # queries a step
    same: int = 9  # negatives of the query's own object a query
    others: int = 3  # negatives of other objects a query
    #: of those, the share drawn from objects with real frames (the rest from every other object, the
    #: procedural shapes mostly): real objects are what a real query is taken for
    others_real: float = 0.0
    far: float = 25.0  # deg: a template of the same object this far from the query's pose is a negative
    tau: float = 0.05  # softmax temperature over the candidates' distances (in [0, 2])
    lr: float = 1e-4  # Adam, cosine decay to 0 over the budget (or max_steps)
    frozen_stages: int = 2  # the trunk's first stages kept as ImageNet's
    real_fraction: float = 0.6  # of a BOP object's queries, real patches of training frames
    real_paste: float = 0.3  # of those, pasted on a random background
    val_negatives: int = 28  # fixed negatives a validation instance (same and other objects, as in training)
    steps_per_epoch: int = 150  # a validation and a checkpoint each
    #: what blacks the queries: a `posedesc train --arch mask` run, or an exported model with a mask
    #: output (.onnx, the service's own mask); "": their true masks
    query_mask: str = ""
    #: px: training queries' masks get an outline this much off, at random (`jitter_outline`); the
    #: service's masks of new frames are wrong mostly there, its masks of training samples hardly at all
    mask_jitter: float = 0.0
    hard_model: str = ""  # an exported model whose descriptor picks `hard` more negatives a query ("": none)
    hard: int = 8  # with `hard_model`: negatives a query among its `hard_pool` nearest templates
    hard_pool: int = 100
    threads: int = 2
    seed: int = 0


class LocalTrunk(Trunk):
    """The trunk with its stages from `frozen` on trainable (BatchNorm keeps ImageNet's statistics)."""

    def __init__(self, frozen: int = 2, pretrained: bool = True):
        super().__init__(pretrained)
        for i, stage in enumerate(self.features):
            for p in stage.parameters():
                p.requires_grad_(i >= frozen)


def distances(fq: torch.Tensor, ft: torch.Tensor, qm: torch.Tensor, sil: torch.Tensor) -> torch.Tensor:
    """`index.features.local.masked_distance` (coverage 0) of each query's map against its K candidates', in torch.
    Shape: fq (B, C, G, G), ft (B, K, C, G, G), qm (B, G * G), sil (B, K, G * G) -> (B, K)."""
    q = F.normalize(fq.flatten(2), dim=1, eps=1e-12)  # each cell a unit vector
    t = F.normalize(ft.flatten(3), dim=2, eps=1e-12)
    cos = (q[:, None] * t).sum(2)

    def weighed(w: torch.Tensor) -> torch.Tensor:
        w = torch.where(w.sum(-1, keepdim=True) > 0, w, torch.ones_like(w))
        return ((1 - cos) * w).sum(-1) / w.sum(-1)

    return 0.5 * (weighed(sil) + weighed(qm[:, None].expand_as(sil)))


class Candidates:
    """Templates to compare a query with: its nearest (first) and the negatives (`LocalConfig`)."""

    def __init__(self, data: TrainingData, cfg: LocalConfig):
        self.data, self.cfg = data, cfg
        self.objects = [
            o for o in range(data.n_objects) if len(data.s_by_obj.get(o, ())) or data.train_real.get(o)
        ]

    def __call__(
        self, obj: int, R: np.ndarray, rng: np.random.Generator, same: int, others: int
    ) -> list[tuple[int, int]]:
        d = pose_distances(R[None], self.data.template_R, self.data.symmetries[obj])[0]
        far = np.flatnonzero(d > self.cfg.far)
        near = np.flatnonzero((d > self.cfg.far) & (d < 70.0))
        picked = list(rng.choice(near, min(len(near), same // 2), replace=False)) if len(near) else []
        picked += list(rng.choice(far, same - len(picked), replace=len(far) < same - len(picked)))
        other = [o for o in range(self.data.n_objects) if o != obj] or [obj]
        real = [o for o in other if self.data.train_real.get(o)] or other
        pools = [real if rng.random() < self.cfg.others_real else other for _ in range(others)]
        rest = [(int(rng.choice(pool)), int(rng.integers(self.data.n_templates))) for pool in pools]
        return [(obj, int(np.argmin(d))), *((obj, int(t)) for t in picked), *rest]


class HardNegatives:
    """The negatives the service's re-ranking meets: templates near a query in an exported model's descriptor
    space (its first stage's candidates), not a pose within `far` of the query's own. Every training
    template (objects and shapes, in-plane variants included) is described once with that model; a query,
    black outside its mask as the service describes it, draws `cfg.hard` of its `cfg.hard_pool` nearest."""

    def __init__(self, data: TrainingData, cfg: LocalConfig, model: Path, chunk: int = 512):
        from index.features.embed import Embedder  # onnxruntime: only this option needs it

        self.data, self.cfg = data, cfg
        self.embed = Embedder(model, cfg.threads)
        keys = [(o, t) for o in range(data.n_objects) for t in range(data.n_templates)]
        described = []
        for i in range(0, len(keys), chunk):
            # one chunk at a time: `template_inputs` would hold every template normalised (~2 GB)
            x = np.stack([data._template_input(o, t, "rgb") for o, t in keys[i : i + chunk]])
            described.append(self.embed(x.astype(np.float32)))
        self.keys = np.asarray(keys)
        self.descriptors = np.concatenate(described)
        self.norms = (self.descriptors**2).sum(1)
        log.info("hard negatives: %d templates described with %s", len(keys), model.name)

    def _allowed(self, dist: np.ndarray, obj: int, R: np.ndarray, n: int) -> np.ndarray:
        """The `n` templates nearest (ascending) but those of `obj` within `far` of the pose R."""
        near = np.argpartition(dist, n - 1)[:n] if n < len(dist) else np.arange(len(dist))
        near = near[np.argsort(dist[near], kind="stable")]
        same = np.flatnonzero(self.keys[near, 0] == obj)
        if len(same):
            poses = self.data.template_R[self.keys[near[same], 1]]
            close = pose_distances(R[None], poses, self.data.symmetries[obj])[0] <= self.cfg.far
            near = np.delete(near, same[close])
        return near

    def __call__(
        self, xq: np.ndarray, objs: list[int], Rs: list[np.ndarray], rng: np.random.Generator
    ) -> list:
        """Black-masked query inputs (B, 3, S, S), their objects and poses -> `cfg.hard` (obj, t) each."""
        d = self.embed(np.ascontiguousarray(xq, np.float32))
        dist = self.norms[None] - 2.0 * d @ self.descriptors.T  # squared L2 but the query's own norm
        out = []
        for b in range(len(xq)):
            near = self._allowed(dist[b], objs[b], Rs[b], 4 * self.cfg.hard_pool)
            if len(near) < self.cfg.hard_pool:  # the query's own views crowd its neighbourhood: look further
                near = self._allowed(dist[b], objs[b], Rs[b], len(dist[b]))
            near = near[: self.cfg.hard_pool]
            picked = rng.choice(near, min(len(near), self.cfg.hard), replace=False)
            out.append([(int(self.keys[i, 0]), int(self.keys[i, 1])) for i in picked])
        return out


def template_inputs(data: TrainingData, cands: list[list[tuple[int, int]]]) -> tuple[np.ndarray, np.ndarray]:
    """The candidates' network inputs (B * K, 3, S, S) and silhouettes (B * K, S, S) bool."""
    xs, sil = [], []
    for row in cands:
        for o, t in row:
            rgb, depth = data.template_patch(o, t)
            xs.append(network_input("rgb", rgb, None, data.cfg.distance, data.cfg.window_mm, fill=False))
            sil.append(depth > 0)
    return np.stack(xs), np.stack(sil)


def jitter_outline(mask: np.ndarray, px: float, rng: np.random.Generator) -> np.ndarray:
    """`mask` with its outline moved in and out by up to `px` pixels, smoothly along it: the signed
    distance to the outline plus a smooth random field (bumps about 11 px apart) scaled to +-`px`,
    cut at 0. Away from the outline (farther than `px`) nothing changes. Shape: (S, S) bool -> same."""
    m = mask.astype(np.uint8)
    if px <= 0 or not m.any() or m.all():
        return mask.copy()
    inside = cv2.distanceTransform(m, cv2.DIST_L2, 3)
    outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, 3)
    signed = np.where(mask, inside, -outside)  # > 0 inside, the outline near 0
    s = mask.shape[0]
    coarse = rng.uniform(-1.0, 1.0, (6, 6)).astype(np.float32)
    smooth = np.asarray(cv2.resize(coarse, (s, s), interpolation=cv2.INTER_CUBIC), np.float32)
    field = smooth / max(float(np.abs(smooth).max()), 1e-6) * px
    return signed + field > 0.5


class OnnxMask:
    """An exported model's mask output (`index.features.embed.MASK_NAME`, the service's own mask) as the local
    trainer's query mask: patches (B, 3, S, S) -> logits (B, 1, S, S), by onnxruntime."""

    def __init__(self, model: Path, threads: int = 1):
        from index.features.embed import MASK_NAME, Embedder

        self.embedder, self.name = Embedder(model, threads), MASK_NAME
        if not self.embedder.has_mask:
            raise ValueError(f"{model} has no mask output")

    def eval(self) -> OnnxMask:
        return self

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        return torch.from_numpy(self.embedder._run(self.name, x.numpy()))


class Scorer:
    """Queries and their candidates -> distances (B, K) through the trunk; the queries black outside the
    mask head's mask (or their true masks)."""

    def __init__(self, data: TrainingData, net: LocalTrunk, mask: MaskNet | OnnxMask | None):
        self.data, self.net, self.mask = data, net, mask
        s = data.spec.size
        black = network_input(
            "rgb", np.zeros((s, s, 3), np.uint8), None, data.cfg.distance, data.cfg.window_mm
        )
        self.black = torch.from_numpy(black)[None]
        self.grid = s // GRID_DIVISOR

    def blacked(
        self, x: np.ndarray, true_masks: np.ndarray, jitter: tuple[float, np.random.Generator] | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The queries as the service describes them, black outside the mask head's masks (or their true
        masks), and those masks; `jitter` (px, rng): each mask's outline moved at random first
        (`jitter_outline`)."""
        xq = torch.from_numpy(x).float()
        if self.mask is not None:
            with torch.no_grad():
                keep = (self.mask(xq) > 0)[:, 0]
        else:
            keep = torch.from_numpy(true_masks)
        if jitter is not None and jitter[0] > 0:
            keep = torch.from_numpy(np.stack([jitter_outline(m, jitter[0], jitter[1]) for m in keep.numpy()]))
        return torch.where(keep[:, None], xq, self.black), keep

    def __call__(
        self,
        x: np.ndarray,
        true_masks: np.ndarray,
        cands: list[list[tuple[int, int]]],
        jitter: tuple[float, np.random.Generator] | None = None,
    ) -> torch.Tensor:
        xq, keep = self.blacked(x, true_masks, jitter)
        tx, ts = template_inputs(self.data, cands)
        k = len(cands[0])
        fq = self.net(xq)
        ft = self.net(torch.from_numpy(tx).float()).view(len(cands), k, *fq.shape[1:])
        qm = torch.from_numpy(cell_weights(keep.numpy(), self.grid))
        sil = torch.from_numpy(cell_weights(ts, self.grid)).view(len(cands), k, -1)
        return distances(fq, ft, qm, sil)


def _batch(
    data: TrainingData,
    cfg: LocalConfig,
    pick: Candidates,
    rng: np.random.Generator,
    hard: HardNegatives | None = None,
    scorer: Scorer | None = None,
) -> tuple:
    xs, ms, cands, objs, Rs = [], [], [], [], []
    for _ in range(cfg.batch):
        obj = int(pick.objects[rng.integers(len(pick.objects))])
        sample, R = data.draw(obj, rng, "rgb", cfg.real_fraction)
        x, m = data.sample_with_mask(sample, "rgb", rng)
        xs.append(x)
        ms.append(m)
        objs.append(obj)
        Rs.append(R)
        cands.append(pick(obj, R, rng, cfg.same, cfg.others))
    x, m = np.stack(xs), np.stack(ms)
    if hard is not None and scorer is not None:
        for row, more in zip(cands, hard(scorer.blacked(x, m)[0].numpy(), objs, Rs, rng), strict=True):
            row += more
    return x, m, cands


def validation_set(data: TrainingData, cfg: LocalConfig, pick: Candidates, split: str = "val") -> tuple:
    """The real instances of `split` cut as the service cuts them with their true masks
    (`training.heads.mask.validation_set`), and fixed candidates for each."""
    rng = np.random.default_rng(cfg.seed + 123)
    xs, ms = mask_validation_set(data, split)
    same = round(cfg.val_negatives * cfg.same / max(1, cfg.same + cfg.others))
    cands = [
        pick(data.real[i].obj, rotations([data.real[i].view])[0], rng, same, cfg.val_negatives - same)
        for i in data.test_instances(split)
    ]
    return xs, ms, cands


def validate(scorer: Scorer, val: tuple, chunk: int = 16) -> float:
    """The share of validation instances whose right template scores best."""
    xs, ms, cands = val
    if len(xs) == 0:
        return 0.0
    with torch.no_grad():
        s = torch.cat(
            [
                scorer(xs[i : i + chunk], ms[i : i + chunk], cands[i : i + chunk])
                for i in range(0, len(xs), chunk)
            ]
        )
    return float((s.argmin(1) == 0).float().mean())


def train_local(
    cfg: LocalConfig,
    data: TrainingData,
    out: Path,
    mask: MaskNet | OnnxMask | None = None,
    command: str = "",
    code: str = "",
    resume: bool = False,
) -> LocalTrunk:
    """Trains for `cfg.minutes` (or `cfg.max_steps`); keeps `local.pt` (every `steps_per_epoch` and the
    last step) and `local-best.pt` (best validation top-1, the ImageNet trunk's score at step 0 first).
    `mask`: the head whose masks black the queries (None: their true masks). `resume`: continue the run
    of `out/local.pt` (made with the same `cfg`)."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed + 11)
    data.cfg.real_paste = cfg.real_paste
    net = LocalTrunk(cfg.frozen_stages)
    trained = [p for p in net.parameters() if p.requires_grad]
    opt = torch.optim.Adam(trained, lr=cfg.lr)
    pick = Candidates(data, cfg)
    scorer = Scorer(data, net, mask.eval() if mask is not None else None)
    val = validation_set(data, cfg, pick)
    hard = HardNegatives(data, cfg, Path(cfg.hard_model)) if cfg.hard_model and cfg.hard > 0 else None
    out.mkdir(parents=True, exist_ok=True)
    budget, step, elapsed, best = cfg.minutes * 60, 0, 0.0, -1.0
    if resume:
        ckpt = torch.load(out / "local.pt", map_location="cpu", weights_only=False)
        state = resume_state(ckpt, asdict(cfg), name=str(out / "local.pt"))
        net.load_state_dict(ckpt["stem"])
        step, (elapsed, best) = ckpt["step"], restore(state, opt, rng)
    t0 = time.perf_counter() - elapsed
    log_path = out / "local-log.jsonl"

    def checkpoint(loss: float | None) -> None:
        nonlocal best
        score = validate(scorer, val)
        rec = {"step": step, "minutes": round(elapsed / 60, 2), "loss": loss, "val_top1": score}
        log.info("local %s", rec)
        print(json.dumps(rec), flush=True)
        state = {"stem": net.state_dict(), "config": asdict(cfg), "step": step, "val_top1": score}
        state |= {"command": command, "code": code}
        if score > best:
            best = score
            save_atomic(state, out / "local-best.pt")
        state["resume"] = progress_state(opt, t0, best, rng)
        save_atomic(state, out / "local.pt")
        with log_path.open("a") as f:
            f.write(json.dumps(rec) + "\n")

    if step == 0:
        checkpoint(None)  # the ImageNet trunk's score: the run keeps it unless training beats it
    saved, loss = step, torch.zeros(())
    while True:
        elapsed = time.perf_counter() - t0
        if elapsed >= budget or (cfg.max_steps and step >= cfg.max_steps):
            if step > saved:
                checkpoint(float(loss.detach()))
            break
        progress = max(elapsed / budget, step / cfg.max_steps if cfg.max_steps else 0.0)
        for g in opt.param_groups:
            g["lr"] = cfg.lr * 0.5 * (1 + math.cos(math.pi * min(1.0, progress)))
        x, m, cands = _batch(data, cfg, pick, rng, hard, scorer)
        s = scorer(x, m, cands, (cfg.mask_jitter, rng))
        loss = F.cross_entropy(-s / cfg.tau, torch.zeros(len(s), dtype=torch.long))
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        if step % cfg.steps_per_epoch == 0:
            checkpoint(float(loss.detach()))
            saved = step
    return net


def load_local(run: Path, which: str = "best") -> tuple[LocalTrunk, dict]:
    path = run / ("local-best.pt" if which == "best" and (run / "local-best.pt").is_file() else "local.pt")
    state = torch.load(path, map_location="cpu", weights_only=False)
    net = LocalTrunk(state["config"]["frozen_stages"], pretrained=False)
    net.load_state_dict(state["stem"])
    return net.eval(), state
