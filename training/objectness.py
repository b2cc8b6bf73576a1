"""The class-agnostic object-centre network of `index/objectness.py`: data, model, loss, training, export.

The frozen ImageNet MobileNetV2 stages (`training/trunk.py`) to stride 8 and 16, and a small trained head
on the stride-8 map (the stride-16 map upsampled beside it; dilated 3 x 3 convolutions so that a cell
sees the whole ~64 px window around it) predicting per cell a centre heatmap (CenterNet's focal loss on
Gaussians around each object's projected origin), the sub-cell offset of the centre, and the log sizes
of the object's 200 mm window and of its projected diameter (L1 at the cells near a centre).

Training samples are crops of real LM-O frames of the TRAIN split, each resized so that one object's
window lands at a random size around `reference_px`, with procedural shapes (`index/shapes.py`) rendered
at random poses and lights and pasted in with soft edges: the network has to find objects it has never
seen, not the seven of LM-O. Objects whose window at the crop's scale is inside `positive_px` are
targets; a band around that range (and objects under `min_visib` visible) is neither target nor
background; objects far out of it are background, so that each object peaks at the pyramid levels
where its window fits. Checkpoints are chosen on the VALIDATION frames' recall.
"""

from __future__ import annotations

import json
import logging
import math
import queue
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import onnx
import torch
import torch.nn.functional as F
from torch import nn
from tqdm import tqdm

from index.bop import BopDataset
from index.mesh import diameter
from index.objectness import INPUT, OUTPUT, WINDOW_MM, Truth, propose_with, recall, truth_of
from index.pose import View
from index.render import Renderer
from index.shapes import random_shape
from training.augment import colour_jitter, soft_edges
from training.render_cache import _random_lighting
from training.splits import split_frames
from training.trunk import DeepStages, Trunk

log = logging.getLogger(__name__)

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
STRIDE = 8
RENDER_SIZE = 128  # shape renders: 128 px over 400 mm, so the 200 mm window spans RENDER_WINDOW px
RENDER_WINDOW_MM = 400.0
RENDER_WINDOW = RENDER_SIZE * WINDOW_MM / RENDER_WINDOW_MM
RENDER_DISTANCE = 1000.0  # mm: LM-O's objects stand 0.35-1.5 m from the camera (median 1.0 m)


@dataclass
class ObjectnessConfig:
    reference_px: float = 64.0  # the window (px at a level) the head is centred on
    positive_px: tuple[float, float] = (40.0, 100.0)  # windows trained as targets (a level's range)
    ignore_px: tuple[float, float] = (30.0, 135.0)  # between these and positive_px: neither
    sample_px: tuple[float, float] = (26.0, 150.0)  # a sample's focus object is scaled into this range
    levels: tuple[float, ...] = (1.0, 0.7071, 0.5, 0.3536, 0.25)  # half-octaves: windows 40-400 px
    min_visib: float = 0.4  # less visible annotated objects are neither target nor background
    sigma: float = 0.8  # the heatmap's Gaussian, cells, for a reference_px window (scales with it)
    crop: int = 192  # training crop side (px at the level)
    batch: int = 16
    width: int = 64  # head channels
    lr: float = 2e-3  # AdamW, cosine decay to lr_end * lr over the budget
    lr_end: float = 0.05
    minutes: float = 35.0  # the optimisation's wall-clock budget
    val_every: int = 400  # steps between validations (and checkpoints)
    shapes: int = 240  # procedural shapes rendered for pasting (~10 a second)
    shape_views: int = 16  # renders of each, random poses and lights
    paste: tuple[int, int] = (0, 4)  # shapes pasted into a sample (uniform, inclusive)
    paste_px: tuple[float, float] = (30.0, 120.0)  # their windows at the crop's scale
    scale_weight: float = 2.0  # of the log window's L1, against the offset's
    seed: int = 0


# ---------------------------------------------------------------- data


@dataclass
class Frame:
    """A real frame and its annotated objects: rows of u, v, window_px, extent_px, visible fraction."""

    frame_id: int
    rgb: np.ndarray
    objects: np.ndarray
    diameters: np.ndarray  # mm, one per object row

    def truths(self, min_visib: float = 0.5) -> list[Truth]:
        return [
            Truth(float(o[0]), float(o[1]), float(o[2]), float(o[3]), float(d))
            for o, d in zip(self.objects, self.diameters, strict=True)
            if o[4] >= min_visib
        ]


def load_frames(root: Path, split: str, scene: int = 2) -> list[Frame]:
    """The frames of one split (`training/splits.py`) of a BOP test scene, with their objects."""
    ds = BopDataset(root)
    insts = list(ds.instances(scene))
    which = split_frames(sorted({i.frame_id for i in insts}))
    frames: dict[int, list] = {}
    for inst in insts:
        if which[inst.frame_id] == split:
            frames.setdefault(inst.frame_id, []).append(inst)
    out = []
    for fid, group in sorted(frames.items()):
        rows, diams = [], []
        for inst in group:
            t = truth_of(inst, float(ds.models_info[inst.obj_id]["diameter"]))
            rows.append([t.u, t.v, t.window_px, t.extent_px, inst.visib_fract])
            diams.append(t.diameter_mm)
        rgb = group[0].load_rgb()
        assert rgb is not None
        out.append(Frame(fid, rgb, np.array(rows, np.float64), np.array(diams)))
    return out


def shape_renders(cfg: ObjectnessConfig, cache_dir: Path) -> dict[str, np.ndarray]:
    """Procedural shapes rendered at random poses and lights, cached: rgb (N, S, S, 3) uint8, mask
    (N, S, S) bool, extent (N,) px of the diameter at the render's scale (the window is RENDER_WINDOW)."""
    path = cache_dir / f"shapes-{cfg.shapes}x{cfg.shape_views}-{cfg.seed}-{RENDER_SIZE}.npz"
    if path.is_file():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    rng = np.random.default_rng(cfg.seed + 1)
    renderer = Renderer(size=RENDER_SIZE, window_mm=RENDER_WINDOW_MM, max_faces=20000)
    rgb, mask, extent = [], [], []
    for _ in tqdm(range(cfg.shapes), desc="render shapes", unit="shape"):
        mesh = random_shape(rng)
        diam = diameter(mesh)
        views = [
            View(
                float(rng.uniform(0, 360)),
                float(rng.uniform(-30, 85)),
                float(rng.uniform(-180, 180)),
                RENDER_DISTANCE,
            )
            for _ in range(cfg.shape_views)
        ]
        for v in views:  # one light each: render() lights a whole call alike
            t = renderer.render(mesh, [v], lighting=_random_lighting(rng))
            rgb.append(t.rgb[0])
            mask.append(t.depth[0] > 0)
            extent.append(RENDER_SIZE * diam / RENDER_WINDOW_MM)
    renderer.close()
    arrays = {"rgb": np.stack(rgb), "mask": np.stack(mask), "extent": np.array(extent, np.float32)}
    cache_dir.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)  # type: ignore[arg-type]  # numpy's stub: a key could be allow_pickle
    return arrays


@dataclass
class Sample:
    """A training crop and its targets on the stride-8 grid (G = crop / 8). heat (G, G): Gaussians, 1 at
    each target's cell; weight (G, G): 0 where the heatmap is not scored; reg (4, G, G): dx, dy (cells),
    log window / reference, log extent / reference; reg_w (G, G): the cells the regression is scored at."""

    img: np.ndarray
    heat: np.ndarray
    weight: np.ndarray
    reg: np.ndarray
    reg_w: np.ndarray


def _paste(
    img: np.ndarray,
    shapes: dict[str, np.ndarray],
    window: float,
    cu: float,
    cv: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, float]:
    """Pastes a random shape render with its origin at (cu, cv) and its window `window` px; returns the
    pasted-on image and the mask of the shape in it. Shape: img (C, C, 3) uint8."""
    k = int(rng.integers(len(shapes["rgb"])))
    f = window / RENDER_WINDOW
    side = max(3, int(round(RENDER_SIZE * f)))
    f = side / RENDER_SIZE
    rgb = cv2.resize(colour_jitter(shapes["rgb"][k], rng, 1.0), (side, side), interpolation=cv2.INTER_AREA)
    m = cv2.resize(shapes["mask"][k].astype(np.uint8), (side, side), interpolation=cv2.INTER_NEAREST) > 0
    # the render's origin is its centre pixel ((S - 1) / 2); place it at (cu, cv)
    x0 = int(round(cu - (side - 1) / 2))
    y0 = int(round(cv - (side - 1) / 2))
    c = img.shape[0]
    ax0, ay0, ax1, ay1 = max(0, x0), max(0, y0), min(c, x0 + side), min(c, y0 + side)
    full = np.zeros(img.shape[:2], bool)
    if ax1 <= ax0 or ay1 <= ay0:
        return full, float(shapes["extent"][k]) * f
    sub_m = m[ay0 - y0 : ay1 - y0, ax0 - x0 : ax1 - x0]
    sub_rgb = rgb[ay0 - y0 : ay1 - y0, ax0 - x0 : ax1 - x0]
    region = img[ay0:ay1, ax0:ax1]
    img[ay0:ay1, ax0:ax1] = np.clip(soft_edges(sub_rgb, region, sub_m, rng), 0, 255).astype(np.uint8)
    full[ay0:ay1, ax0:ax1] = sub_m
    return full, float(shapes["extent"][k]) * f


def make_sample(
    frames: list[Frame], shapes: dict[str, np.ndarray], cfg: ObjectnessConfig, rng: np.random.Generator
) -> Sample:
    """One random training crop: a real train frame scaled and cropped, shapes pasted, colours jittered."""
    fr = frames[int(rng.integers(len(frames)))]
    objs = fr.objects
    seen = np.nonzero(objs[:, 4] >= cfg.min_visib)[0]
    c = cfg.crop
    h, w = fr.rgb.shape[:2]
    if len(seen) and rng.random() < 0.85:
        focus = objs[int(rng.choice(seen))]
        s = math.exp(rng.uniform(*np.log(cfg.sample_px))) / focus[2]
        cu, cv = focus[0] + rng.uniform(-0.4, 0.4) * c / s, focus[1] + rng.uniform(-0.4, 0.4) * c / s
    else:
        s = math.exp(rng.uniform(math.log(0.2), math.log(1.2)))
        cu, cv = rng.uniform(0, w), rng.uniform(0, h)
    lw, lh = max(1, round(w * s)), max(1, round(h * s))
    level = cv2.resize(fr.rgb, (lw, lh), interpolation=cv2.INTER_AREA)
    sx, sy = lw / w, lh / h
    # the crop's top-left in level pixels; outside the level is black, as the pyramid's padding
    x0 = int(round((cu + 0.5) * sx - 0.5 - c / 2))
    y0 = int(round((cv + 0.5) * sy - 0.5 - c / 2))
    # kept inside the level where it is larger than the crop: black is for levels smaller than a crop
    x0, y0 = (
        int(np.clip(x0, min(0, lw - c), max(0, lw - c))),
        int(np.clip(y0, min(0, lh - c), max(0, lh - c))),
    )
    img = np.zeros((c, c, 3), np.uint8)
    ax0, ay0, ax1, ay1 = max(0, x0), max(0, y0), min(lw, x0 + c), min(lh, y0 + c)
    if ax1 > ax0 and ay1 > ay0:
        img[ay0 - y0 : ay1 - y0, ax0 - x0 : ax1 - x0] = level[ay0:ay1, ax0:ax1]
    # rows: u, v, window, extent, visible fraction, in crop pixels
    rows = [
        [
            (o[0] + 0.5) * sx - 0.5 - x0,
            (o[1] + 0.5) * sy - 0.5 - y0,
            o[2] * (sx + sy) / 2,
            o[3] * (sx + sy) / 2,
            o[4],
        ]
        for o in objs
    ]
    for _ in range(int(rng.integers(cfg.paste[0], cfg.paste[1] + 1))):
        win = math.exp(rng.uniform(*np.log(cfg.paste_px)))
        pu, pv = rng.uniform(-0.1, 1.1) * c, rng.uniform(-0.1, 1.1) * c
        m, ext = _paste(img, shapes, win, pu, pv, rng)
        for r in rows:  # an object whose origin the shape now covers counts as hidden
            iu, iv = int(round(r[0])), int(round(r[1]))
            if 0 <= iu < c and 0 <= iv < c and m[iv, iu]:
                r[4] = 0.0
        rows.append([pu, pv, win, ext, 1.0])
    if rng.random() < 0.5:  # a mirrored object is still an object
        img = img[:, ::-1]
        for r in rows:
            r[0] = c - 1 - r[0]
    img = colour_jitter(np.ascontiguousarray(img), rng, 1.0)
    if rng.random() < 0.3:  # a camera's focus and motion
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), rng.uniform(0.3, 1.2)), np.uint8)
    return Sample(img, *_targets(np.array(rows, np.float64).reshape(-1, 5), cfg))


def _targets(rows: np.ndarray, cfg: ObjectnessConfig) -> tuple[np.ndarray, ...]:
    g = cfg.crop // STRIDE
    centres = STRIDE * np.arange(g) + (STRIDE - 1) / 2
    heat = np.zeros((g, g), np.float32)
    weight = np.ones((g, g), np.float32)
    reg = np.zeros((4, g, g), np.float32)
    reg_w = np.zeros((g, g), np.float32)
    best = np.zeros((g, g), np.float32)  # the Gaussian a cell's regression target belongs to
    lo, hi = cfg.positive_px
    for u, v, win, ext, vis in rows:
        if vis < 0.1:
            continue  # hidden: background
        positive = lo <= win <= hi and vis >= cfg.min_visib
        near = cfg.ignore_px[0] <= win <= cfg.ignore_px[1]
        if not positive and not near:
            continue  # far out of the head's range: background
        dist2 = (centres[None, :] - u) ** 2 + (centres[:, None] - v) ** 2
        if not positive:  # the band around the range, or too hidden: not scored near its centre
            weight[dist2 <= (0.25 * win) ** 2] = 0.0
            continue
        sig = cfg.sigma * STRIDE * win / cfg.reference_px
        gauss = np.exp(-dist2 / (2 * sig * sig)).astype(np.float32)
        j, i = int(round((u - (STRIDE - 1) / 2) / STRIDE)), int(round((v - (STRIDE - 1) / 2) / STRIDE))
        if 0 <= i < g and 0 <= j < g:
            gauss[i, j] = 1.0
        np.maximum(heat, gauss, out=heat)
        cells = (gauss > 0.5) & (gauss > best)
        best[cells] = gauss[cells]
        ii, jj = np.nonzero(cells)
        reg[0, ii, jj] = (u - centres[jj]) / STRIDE
        reg[1, ii, jj] = (v - centres[ii]) / STRIDE
        reg[2, ii, jj] = math.log(win / cfg.reference_px)
        reg[3, ii, jj] = math.log(ext / cfg.reference_px)
        reg_w[ii, jj] = gauss[ii, jj]
    return heat, weight, reg, reg_w


# ---------------------------------------------------------------- model


class ObjectnessHead(nn.Module):
    """Stride-8 features (and stride-16 upsampled) -> 5 maps. Shape: (B, 32, H/8, W/8), (B, 64, H/16,
    W/16) -> (B, 5, H/8, W/8): centre logit, dx, dy, log window, log extent."""

    def __init__(self, width: int = 64):
        super().__init__()

        def block(cin: int, dilation: int) -> nn.Sequential:
            return nn.Sequential(
                nn.Conv2d(cin, width, 3, padding=dilation, dilation=dilation, bias=False),
                nn.BatchNorm2d(width),
                nn.ReLU(inplace=True),
            )

        # dilations 1, 2, 4, 1 add 16 cells (128 px at stride 8) of receptive field
        self.body = nn.Sequential(block(32 + 64, 1), block(width, 2), block(width, 4), block(width, 1))
        self.out = nn.Conv2d(width, 5, 1)
        bias = self.out.bias
        assert bias is not None  # Conv2d's default
        with torch.no_grad():
            bias.zero_()
            bias[0] = -4.6  # a prior of 1 % centres: the focal loss starts calm (RetinaNet)

    def forward(self, d8: torch.Tensor, d16: torch.Tensor) -> torch.Tensor:
        up = F.interpolate(d16, scale_factor=2.0, mode="nearest")
        return self.out(self.body(torch.cat([d8, up], dim=1)))


class ObjectnessNet(nn.Module):
    """Frozen pretrained stages and the trained head. Shape: (B, 3, H, W) RGB 0-255, H and W multiples
    of 16 -> (B, 5, H/8, W/8) (raw: a logit in channel 0)."""

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, width: int = 64, pretrained: bool = True):
        super().__init__()
        self.trunk, self.deep = Trunk(pretrained), DeepStages(pretrained)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1) * 255.0)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1) * 255.0)
        self.head = ObjectnessHead(width)

    def features(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.deep(self.trunk((x - self.mean) / self.std))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(*self.features(x))


class Scored(nn.Module):
    """What is exported: channel 0 as a score (sigmoid), the rest as they are."""

    def __init__(self, net: ObjectnessNet):
        super().__init__()
        self.net = net

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        y = self.net(rgb)
        return torch.cat([torch.sigmoid(y[:, :1]), y[:, 1:]], dim=1)


def centre_loss(logit: torch.Tensor, heat: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss (Zhou et al. 2019), per target. Shape: (B, G, G) x3."""
    p = torch.sigmoid(logit).clamp(1e-4, 1 - 1e-4)
    pos = heat >= 1.0
    pos_loss = -torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = -torch.log(1 - p) * p**2 * (1 - heat) ** 4 * (~pos)
    return ((pos_loss + neg_loss) * weight).sum() / pos.sum().clamp(min=1)


def regression_loss(
    pred: torch.Tensor, reg: torch.Tensor, reg_w: torch.Tensor, scale_weight: float
) -> torch.Tensor:
    """L1 of offset and log sizes at the cells near a centre. Shape: (B, 4, G, G) x2, (B, G, G)."""
    err = (pred - reg).abs()
    per = err[:, 0] + err[:, 1] + scale_weight * err[:, 2] + err[:, 3]
    return (per * reg_w).sum() / reg_w.sum().clamp(min=1)


# ---------------------------------------------------------------- training


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
    """`net` as `index.objectness.Run`: (1, 3, H, W) float32 -> (5, h, w) with a score in channel 0."""
    scored = Scored(net).eval()

    def run(x: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return scored(torch.from_numpy(x))[0].numpy()

    return run


def validate(net: ObjectnessNet, frames: list[Frame], cfg: ObjectnessConfig, limit: int = 30) -> dict:
    """Recall of the frames' objects (visible >= 0.5) among their proposals, by window and by extent."""
    net.eval()
    run = torch_runner(net)
    pairs = [
        (propose_with(run, f.rgb, cfg.levels, STRIDE, cfg.reference_px, limit), f.truths()) for f in frames
    ]
    net.head.train()
    return {
        "window": recall(pairs),
        "extent": recall(pairs, by_extent=True),
        "n": sum(len(t) for _, t in pairs),
    }


def score_of(figures: dict) -> float:
    """What picks the checkpoint: the tight and the loose recall in the top 20, averaged."""
    w = figures["window"]
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
    shapes = shape_renders(cfg, cache_dir)
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
                score = score_of(figures)
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
    """The network as one ONNX file (dynamic H, W) with what `index.objectness.ObjectnessNet` reads.
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
