"""The foreground mask: which pixels of a patch belong to the object at its centre.

A descriptor of a cluttered patch describes the clutter too. Sent black outside the true visible mask
(`posedesc evaluate --oracle-mask`), the shipped rgb model's answers on the validation frames went from
32 % to 75 % within 20 deg and from 50 % to 94 % right object: what stands around the object, not the
descriptor, was what limited it. So a small head predicts the mask, and the service blacks out the rest
before the descriptor sees the patch (`index.features.embed.Embedder.embed_patches`, `masked`).

The head sits on the descriptor's own frozen trunk (`training/trunk.py`: 16 x 16 x 24 at 64 px), with
two channels of image coordinates (the object is the one at the centre, so where a pixel is matters) and
dilated convolutions so that every cell sees the whole patch; its edges are drawn on the trunk's earlier
32 x 32 map, and the logits upsampled to the patch. It is trained on the samples descriptor training draws (`TrainingData.sample_with_mask`):
procedural shapes and BOP objects rendered over backgrounds with clutter and occluders, and real patches
of the training frames, their masks rendered from the ground truth. Objects left out of training never
reach it either."""

from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from index.features.patches import crop, network_input
from training.data import TrainingData
from training.resume import progress_state, restore, resume_state, save_atomic
from training.trunk import EARLY_CHANNELS, TRUNK_CHANNELS, DeepStages, Trunk

log = logging.getLogger(__name__)


@dataclass
class MaskConfig:
    minutes: float = 12.0  # wall-clock budget
    max_steps: int = 0  # also stop after this many steps (0: only the budget)
    batch: int = 64
    lr: float = 2e-3  # Adam, cosine decay to lr * 0.05 over the budget (or max_steps, if they end first)
    real_fraction: float = 0.6  # of a BOP object's samples, real patches of training frames
    real_paste: float = 0.3  # of those, pasted on a random background (the rest keep their real clutter)
    steps_per_epoch: int = 200  # a validation and a checkpoint each
    #: > 0: the head gets its own copy of the trunk, and it and the later stages are trained too, at the
    #: learning rate times this (0: the descriptor's frozen trunk and stages, shared with it at export)
    finetune: float = 0.0
    #: > 0: the loss of pixels within `OUTLINE_PX` of the true outline counts 1 + this times (the service's
    #: masks of new frames are wrong mostly there, and the re-ranking's cells along it decide the pose)
    outline_weight: float = 0.0
    #: chance a synthetic sample's object is blended into its background over a soft, per-channel shifted
    #: edge (`training.augment.soft_edges`), as a camera's edges are, instead of a render's hard one
    soft_edges: float = 0.0
    colour_jitter: float = 0.0  # the samples' random gamma / saturation / contrast / hue (DataConfig's)
    threads: int = 2
    seed: int = 0


#: pixels at most this far from the true outline are the outline (`outline_band`)
OUTLINE_PX = 2


def outline_band(m: torch.Tensor, px: int = OUTLINE_PX) -> torch.Tensor:
    """1 where a pixel lies within `px` (chessboard distance) of the mask's outline, on either side, else
    0. Shape: (B, 1, H, W) float in {0, 1} -> same."""
    k = 2 * px + 1
    dilated = F.max_pool2d(m, k, stride=1, padding=px)
    eroded = -F.max_pool2d(-m, k, stride=1, padding=px)
    return dilated - eroded


def mask_loss(logits: torch.Tensor, m: torch.Tensor, outline_weight: float = 0.0) -> torch.Tensor:
    """Per-pixel cross-entropy (the outline's pixels weighted 1 + `outline_weight`) plus the soft Dice
    loss. Shapes: (B, 1, H, W) logits and masks -> ()."""
    w = None if outline_weight <= 0 else 1.0 + outline_weight * outline_band(m)
    return F.binary_cross_entropy_with_logits(logits, m, weight=w) + _dice(logits, m)


def _coords(like: torch.Tensor) -> torch.Tensor:
    """Two channels of image coordinates in [-1, 1] (y, x) shaped like `like`'s map. Shape: (B, 2, H, W)."""
    b, _, h, w = like.shape
    ys = torch.linspace(-1.0, 1.0, h, dtype=like.dtype).view(1, 1, h, 1).expand(b, 1, h, w)
    xs = torch.linspace(-1.0, 1.0, w, dtype=like.dtype).view(1, 1, 1, w).expand(b, 1, h, w)
    return torch.cat([ys, xs], dim=1)


def _block(cin: int, cout: int, dilation: int = 1) -> list[nn.Module]:
    return [
        nn.Conv2d(cin, cout, 3, padding=dilation, dilation=dilation, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(),
    ]


class MaskHead(nn.Module):
    """The trunk's maps -> mask logits at the patch's size: which object is the centred one is decided on
    the trunk's map with the frozen later stages of MobileNetV2 (`DeepStages`, upsampled to it) and
    dilated convolutions (every cell sees the whole patch), where its edges run on the map of twice the
    resolution. Shape: (B, 16, S/2, S/2), (B, 24, S/4, S/4) -> (B, 1, S, S)."""

    def __init__(self, width: int = 48, fine: int = 32, pretrained: bool = True):
        super().__init__()
        self.deep = DeepStages(pretrained)
        self.context = nn.Sequential(
            *_block(TRUNK_CHANNELS + 32 + 64 + 2, width), *_block(width, width, 2), *_block(width, width, 4)
        )
        self.edges = nn.Sequential(*_block(width + EARLY_CHANNELS + 2, fine), *_block(fine, fine))
        self.out = nn.Conv2d(fine, 1, 1)

    def forward(self, early: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
        d8, d16 = self.deep(m)
        up8 = F.interpolate(d8, scale_factor=2.0, mode="bilinear", align_corners=False)
        up16 = F.interpolate(d16, scale_factor=4.0, mode="bilinear", align_corners=False)
        c = self.context(torch.cat([m, up8, up16, _coords(m)], dim=1))
        c = F.interpolate(c, scale_factor=2.0, mode="bilinear", align_corners=False)
        logits = self.out(self.edges(torch.cat([c, early, _coords(early)], dim=1)))
        return F.interpolate(logits, scale_factor=2.0, mode="bilinear", align_corners=False)


class MaskNet(nn.Module):
    """Patch -> mask logits: the trunk and the head. Shape: (B, 3, S, S) -> (B, 1, S, S). `own_stem`:
    the trunk and the head's later stages are trainable (fine-tuned for the mask: `MaskConfig.finetune`),
    so the exported model runs this trunk for the mask besides the descriptor's frozen one."""

    def __init__(self, pretrained: bool = True, own_stem: bool = False):
        super().__init__()
        self.own_stem = own_stem
        self.stem = Trunk(pretrained)
        self.head = MaskHead(pretrained=pretrained)
        if own_stem:
            self.stem.unfreeze()
            self.head.deep.unfreeze()

    def backbone(self) -> list[nn.Parameter]:
        """The pretrained weights being fine-tuned (none when frozen)."""
        return [p for p in [*self.stem.parameters(), *self.head.deep.parameters()] if p.requires_grad]

    def own(self) -> list[nn.Parameter]:
        """The head's own weights (trained from scratch)."""
        deep = {id(p) for p in self.head.deep.parameters()}
        return [p for p in self.head.parameters() if id(p) not in deep]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(*self.stem.stages(x))


def _batch(
    data: TrainingData, cfg: MaskConfig, rng: np.random.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    xs, ms = [], []
    for _ in range(cfg.batch):
        obj = int(rng.integers(data.n_objects))
        sample, _ = data.draw(obj, rng, "rgb", cfg.real_fraction)
        x, m = data.sample_with_mask(sample, "rgb", rng)
        xs.append(x)
        ms.append(m)
    return torch.from_numpy(np.stack(xs)).float(), torch.from_numpy(np.stack(ms)[:, None]).float()


def validation_set(data: TrainingData, split: str = "val") -> tuple[np.ndarray, np.ndarray]:
    """The real instances of `split` cut as the service cuts them (true centre and distance, the camera's
    roll), with their true visible masks: inputs (N, 3, S, S) and masks (N, S, S) bool."""
    xs, ms = [], []
    for i in data.test_instances(split):
        r = data.real[i]
        mask3 = np.repeat(((data.labels[r.frame] == r.obj + 1) * 255).astype(np.uint8)[..., None], 3, 2)
        rgb, _ = crop(data.frames[r.frame], None, r.K, r.centre_uv, r.view.distance, data.spec)
        m, _ = crop(mask3, None, r.K, r.centre_uv, r.view.distance, data.spec)
        xs.append(network_input("rgb", rgb, None, data.cfg.distance, data.cfg.window_mm))
        ms.append(m[..., 0] > 127)
    if not xs:
        s = data.spec.size
        return np.zeros((0, 3, s, s), np.float32), np.zeros((0, s, s), bool)
    return np.stack(xs), np.stack(ms)


def mask_iou(logits: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """Intersection over union of each predicted mask (logits > 0) with the true one. Shape: (N,)."""
    pred = logits.reshape(masks.shape) > 0
    inter = (pred & masks).sum(axis=(1, 2))
    union = (pred | masks).sum(axis=(1, 2))
    return inter / np.maximum(union, 1)


def predict(net: MaskNet, x: np.ndarray, batch: int = 256) -> np.ndarray:
    with torch.no_grad():
        net.eval()
        return np.concatenate(
            [net(torch.from_numpy(x[i : i + batch]).float()).numpy() for i in range(0, len(x), batch)]
        )


def train_mask(
    cfg: MaskConfig, data: TrainingData, out: Path, command: str = "", code: str = "", resume: bool = False
) -> MaskNet:
    """Trains the head for `cfg.minutes` (or `cfg.max_steps`); keeps `mask.pt` (every `steps_per_epoch`
    and the last step) and `mask-best.pt` (best validation IoU). `resume`: continue the run of `out/mask.pt` (made with the same `cfg`)."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed + 7)
    # batch-time choices: real clutter is what the head must learn
    data.cfg.real_paste = cfg.real_paste
    data.cfg.soft_edges, data.cfg.colour_jitter = cfg.soft_edges, cfg.colour_jitter
    net = MaskNet(own_stem=cfg.finetune > 0)
    groups = [{"params": net.own(), "scale": 1.0}]
    if cfg.finetune > 0:
        groups.append({"params": net.backbone(), "scale": cfg.finetune})
    opt = torch.optim.Adam(groups, lr=cfg.lr)
    val_x, val_m = validation_set(data)
    out.mkdir(parents=True, exist_ok=True)
    budget, step, elapsed, best = cfg.minutes * 60, 0, 0.0, -1.0
    if resume:
        ckpt = torch.load(out / "mask.pt", map_location="cpu", weights_only=False)
        state = resume_state(ckpt, asdict(cfg), name=str(out / "mask.pt"))
        net.head.load_state_dict(ckpt["head"])
        if "stem" in ckpt:
            net.stem.load_state_dict(ckpt["stem"])
        step, (elapsed, best) = ckpt["step"], restore(state, opt, rng)
    t0 = time.perf_counter() - elapsed  # the budget and the schedule go on from the time already spent
    log_path = out / "mask-log.jsonl"

    def checkpoint(loss: float) -> None:
        nonlocal best
        score = float(mask_iou(predict(net, val_x), val_m).mean()) if len(val_x) else 0.0
        rec = {"step": step, "minutes": round(elapsed / 60, 2), "loss": loss, "val_iou": score}
        log.info("mask %s", rec)
        print(json.dumps(rec), flush=True)
        state = {
            "head": net.head.state_dict(),
            **({"stem": net.stem.state_dict()} if net.own_stem else {}),
            "config": asdict(cfg),
            "step": step,
            "val_iou": score,
            "command": command,
            "code": code,
        }
        if score > best:
            best = score
            save_atomic(state, out / "mask-best.pt")
        # mask-best.pt before mask.pt: a run killed between the two redoes these steps and both
        state["resume"] = progress_state(opt, t0, best, rng)
        save_atomic(state, out / "mask.pt")
        with log_path.open("a") as f:
            f.write(json.dumps(rec) + "\n")

    saved, loss = step, torch.zeros(())
    while True:
        elapsed = time.perf_counter() - t0
        if elapsed >= budget or (cfg.max_steps and step >= cfg.max_steps):
            if step > saved:  # the last steps, so that mask.pt is the end of the run
                checkpoint(float(loss.detach()))
            break
        # cosine decay over the budget, or over max_steps when they end first (so --seed runs repeat)
        progress = max(elapsed / budget, step / cfg.max_steps if cfg.max_steps else 0.0)
        for g in opt.param_groups:
            g["lr"] = g["scale"] * cfg.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(1.0, progress))))
        net.head.train()
        x, m = _batch(data, cfg, rng)
        logits = net(x)
        loss = mask_loss(logits, m, cfg.outline_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        if step % cfg.steps_per_epoch == 0:
            checkpoint(float(loss.detach()))
            saved = step
    return net


def _dice(logits: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    p = torch.sigmoid(logits)
    inter = (p * m).sum(dim=(1, 2, 3))
    return (1 - (2 * inter + 1) / (p.sum(dim=(1, 2, 3)) + m.sum(dim=(1, 2, 3)) + 1)).mean()


def load_mask(run: Path, which: str = "best") -> tuple[MaskNet, dict]:
    path = run / ("mask-best.pt" if which == "best" and (run / "mask-best.pt").is_file() else "mask.pt")
    state = torch.load(path, map_location="cpu", weights_only=False)
    net = MaskNet(own_stem="stem" in state)
    net.head.load_state_dict(state["head"])
    if "stem" in state:
        net.stem.load_state_dict(state["stem"])
    return net.eval(), state
