"""The objectness network's training samples: crops of real frames of the train split with procedural shapes pasted in, and the targets each crop's objects make."""

from __future__ import annotations

import math
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from index.data.bop import BopDataset
from index.geometry.pose import View
from index.templates.mesh import diameter
from index.templates.render import Renderer
from index.templates.shapes import random_shape
from training.augment import colour_jitter, soft_edges
from training.objectness.config import (
    RENDER_DISTANCE,
    RENDER_SIZE,
    RENDER_WINDOW,
    RENDER_WINDOW_MM,
    STRIDE,
    ObjectnessConfig,
)
from training.objectness.recall import Truth, truth_of
from training.render_cache import _random_lighting
from training.splits import split_frames


@dataclass
class Frame:
    """A real frame and its annotated objects: rows of u, v, window_px, extent_px, visible fraction."""

    frame_id: int
    rgb: np.ndarray
    objects: np.ndarray
    diameters: np.ndarray  # mm, one per object row
    ids: np.ndarray  # the object id of each row

    def truths(self, min_visib: float = 0.5, only: Collection[int] | None = None) -> list[Truth]:
        """The objects at least `min_visib` visible (of the ids `only`, default all)."""
        return [
            Truth(float(o[0]), float(o[1]), float(o[2]), float(o[3]), float(d))
            for o, d, i in zip(self.objects, self.diameters, self.ids, strict=True)
            if o[4] >= min_visib and (only is None or int(i) in only)
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
        ids = np.array([i.obj_id for i in group])
        out.append(Frame(fid, rgb, np.array(rows, np.float64), np.array(diams), ids))
    return out


def photos_of(frames: list[Frame], rng: np.random.Generator, n: int = 200) -> list[np.ndarray]:
    """`n` crops (96-256 px) of the frames that overlap none of their annotated objects' boxes (a window
    around each origin): real surfaces, no annotated object in them. Fewer when the frames hold fewer."""
    out: list[np.ndarray] = []
    for _ in range(n * 20):
        if len(out) >= n:
            break
        fr = frames[int(rng.integers(len(frames)))]
        h, w = fr.rgb.shape[:2]
        side = int(rng.integers(96, 257))
        x0, y0 = int(rng.integers(0, w - side)), int(rng.integers(0, h - side))
        hit = False
        for u, v, win, *_ in fr.objects:
            r = win / 2
            if u + r > x0 and u - r < x0 + side and v + r > y0 and v - r < y0 + side:
                hit = True
                break
        if not hit:
            out.append(fr.rgb[y0 : y0 + side, x0 : x0 + side].copy())
    return out


def shape_renders(
    cfg: ObjectnessConfig, cache_dir: Path, photos: list[np.ndarray] | None = None
) -> dict[str, np.ndarray]:
    """The objects to paste (`cfg.objects`: procedural shapes, or the catalogue of
    `training/objectness/catalogue.py`) rendered at random poses and lights, cached: rgb (N, S, S, 3) uint8,
    mask (N, S, S) bool, extent (N,) px of the diameter at the render's scale (the window is RENDER_WINDOW)."""
    kind = "shapes" if cfg.objects == "shapes" else "catalogue"
    photo = f"-photo{cfg.photo_share:g}" if kind == "catalogue" and cfg.photo_share > 0 else ""
    path = cache_dir / f"{kind}-{cfg.shapes}x{cfg.shape_views}-{cfg.seed}-{RENDER_SIZE}{photo}.npz"
    if path.is_file():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    rng = np.random.default_rng(cfg.seed + 1)
    paths: list[Path] = []
    if kind == "catalogue":
        from training.objectness.catalogue import catalogue  # noqa: PLC0415  # pybullet: catalogue runs only

        paths = catalogue()
    renderer = Renderer(size=RENDER_SIZE, window_mm=RENDER_WINDOW_MM, max_faces=20000)
    rgb, mask, extent = [], [], []
    for i in tqdm(range(cfg.shapes), desc=f"render {kind}", unit="object"):
        if kind == "catalogue":
            from training.objectness.catalogue import catalogue_object  # noqa: PLC0415

            mesh = catalogue_object(paths, i, rng, photos=photos, photo_share=cfg.photo_share)
        else:
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
            if not (t.depth[0] > 0).any():
                continue  # nothing in the window (cannot happen at 1 m for 300 mm, but never paste nothing)
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
    negative: bool = False,
    harmonise: float = 0.0,
) -> tuple[np.ndarray, float]:
    """Pastes a random shape render with its origin at (cu, cv) and its window `window` px; returns the
    mask of the shape in the image and its extent. `negative`: the silhouette filled with another part of
    the image instead (an outline with no object's shading: background). Shape: img (C, C, 3) uint8."""
    k = int(rng.integers(len(shapes["rgb"])))
    f = window / RENDER_WINDOW
    side = max(3, int(round(RENDER_SIZE * f)))
    f = side / RENDER_SIZE
    c = img.shape[0]
    if negative:
        sx, sy = (int(rng.integers(0, max(1, c - side + 1))) for _ in range(2))
        rgb: np.ndarray = np.zeros((side, side, 3), np.uint8)
        part = img[sy : sy + side, sx : sx + side]
        rgb[: part.shape[0], : part.shape[1]] = part
    else:
        rgb = cv2.resize(
            colour_jitter(shapes["rgb"][k], rng, 1.0), (side, side), interpolation=cv2.INTER_AREA
        )
    m = cv2.resize(shapes["mask"][k].astype(np.uint8), (side, side), interpolation=cv2.INTER_NEAREST) > 0
    # the render's origin is its centre pixel ((S - 1) / 2); place it at (cu, cv)
    x0 = int(round(cu - (side - 1) / 2))
    y0 = int(round(cv - (side - 1) / 2))
    ax0, ay0, ax1, ay1 = max(0, x0), max(0, y0), min(c, x0 + side), min(c, y0 + side)
    full = np.zeros(img.shape[:2], bool)
    if ax1 <= ax0 or ay1 <= ay0:
        return full, float(shapes["extent"][k]) * f
    sub_m = m[ay0 - y0 : ay1 - y0, ax0 - x0 : ax1 - x0]
    sub_rgb = rgb[ay0 - y0 : ay1 - y0, ax0 - x0 : ax1 - x0]
    region = img[ay0:ay1, ax0:ax1]
    if not negative and sub_m.any() and rng.random() < harmonise:  # the scene's light and white balance
        shift = region.reshape(-1, 3).mean(axis=0) - sub_rgb[sub_m].mean(axis=0)
        sub_rgb = np.clip(sub_rgb + rng.uniform(0.0, 0.4) * shift, 0, 255).astype(np.uint8)
    img[ay0:ay1, ax0:ax1] = np.clip(soft_edges(sub_rgb, region, sub_m, rng), 0, 255).astype(np.uint8)
    full[ay0:ay1, ax0:ax1] = sub_m
    return full, float(shapes["extent"][k]) * f


def make_sample(
    frames: list[Frame], shapes: dict[str, np.ndarray], cfg: ObjectnessConfig, rng: np.random.Generator
) -> Sample:
    """One random training crop: a real train frame scaled and cropped, shapes pasted, colours jittered."""
    fr = frames[int(rng.integers(len(frames)))]
    objs = fr.objects
    held = np.isin(fr.ids, cfg.holdout) | (cfg.real_objects == "held")
    scrambled = rng.random() < cfg.scrambled
    seen = np.nonzero((objs[:, 4] >= cfg.min_visib) & ~held)[0]
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
    real = np.zeros((c, c), bool)  # the crop's pixels of the real frame (the rest is the pyramid's black)
    ax0, ay0, ax1, ay1 = max(0, x0), max(0, y0), min(lw, x0 + c), min(lh, y0 + c)
    if ax1 > ax0 and ay1 > ay0:
        img[ay0 - y0 : ay1 - y0, ax0 - x0 : ax1 - x0] = level[ay0:ay1, ax0:ax1]
        real[ay0 - y0 : ay1 - y0, ax0 - x0 : ax1 - x0] = True
    # rows: u, v, window, extent, visible fraction, kind (REAL, PASTED, HELD), in crop pixels
    rows = [
        [
            (o[0] + 0.5) * sx - 0.5 - x0,
            (o[1] + 0.5) * sy - 0.5 - y0,
            o[2] * (sx + sy) / 2,
            o[3] * (sx + sy) / 2,
            o[4],
            HELD if h else REAL,
        ]
        for o, h in zip(objs, held, strict=True)
    ]
    if scrambled:  # no object survives its tiles being shuffled: every real cell is background
        img = _shuffled_tiles(img, rng)
        rows = []
    decoys = np.zeros((c, c), bool)  # negative pastes: background wherever they are
    n_paste = int(rng.integers(cfg.paste[0], cfg.paste[1] + 1))
    # decoys first: what fills them is then never a pasted object
    for negative in sorted((rng.random() < cfg.negative_paste for _ in range(n_paste)), reverse=True):
        win = math.exp(rng.uniform(*np.log(cfg.paste_px)))
        pu, pv = rng.uniform(-0.1, 1.1) * c, rng.uniform(-0.1, 1.1) * c
        m, ext = _paste(img, shapes, win, pu, pv, rng, negative, cfg.harmonise)
        for r in rows:  # an object whose origin the shape now covers counts as hidden
            iu, iv = int(round(r[0])), int(round(r[1]))
            if 0 <= iu < c and 0 <= iv < c and m[iv, iu]:
                r[4] = 0.0
        if negative:
            decoys |= m
        else:
            decoys &= ~m
            rows.append([pu, pv, win, ext, 1.0, PASTED])
    if rng.random() < 0.5:  # a mirrored object is still an object
        img, real, decoys = img[:, ::-1], real[:, ::-1], decoys[:, ::-1]
        for r in rows:
            r[0] = c - 1 - r[0]
    img = colour_jitter(np.ascontiguousarray(img), rng, 1.0)
    if rng.random() < 0.3:  # a camera's focus and motion
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), rng.uniform(0.3, 1.2)), np.uint8)
    # where nobody said what is there: a real frame's cells outside its objects, when only they are scored
    unknown = None
    if cfg.background == "ignore" and not scrambled:
        unknown = (
            cv2.resize(real.astype(np.float32), (c // STRIDE, c // STRIDE), interpolation=cv2.INTER_AREA) > 0
        )
        if decoys.any():  # a decoy's cells are known background
            cells = cv2.resize(
                decoys.astype(np.float32), (c // STRIDE, c // STRIDE), interpolation=cv2.INTER_AREA
            )
            unknown &= ~(cells > 0.5)
    return Sample(img, *_targets(np.array(rows, np.float64).reshape(-1, 6), cfg, unknown))


REAL, PASTED, HELD = 0, 1, 2  # a sample row's kind: an annotated object, a pasted shape, a held-out object


def _shuffled_tiles(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The crop cut in square tiles of 12-40 px, shuffled: the frame's colours and textures, no object."""
    c = img.shape[0]
    t = int(rng.integers(12, 41))
    n = -(-c // t)
    big = np.zeros((n * t, n * t, 3), np.uint8)
    big[:c, :c] = img
    tiles = big.reshape(n, t, n, t, 3).transpose(0, 2, 1, 3, 4).reshape(n * n, t, t, 3)
    tiles = tiles[rng.permutation(n * n)]
    tiles = np.rot90(tiles, int(rng.integers(4)), axes=(1, 2))
    out = tiles.reshape(n, n, t, t, 3).transpose(0, 2, 1, 3, 4).reshape(n * t, n * t, 3)
    return np.ascontiguousarray(out[:c, :c])


def _targets(
    rows: np.ndarray, cfg: ObjectnessConfig, unknown: np.ndarray | None = None
) -> tuple[np.ndarray, ...]:
    """The crop's targets from its rows (`make_sample`). `unknown` (G, G): the cells nothing is known of
    (unscored unless near an object), None: every cell is scored."""
    g = cfg.crop // STRIDE
    centres = STRIDE * np.arange(g) + (STRIDE - 1) / 2
    heat = np.zeros((g, g), np.float32)
    weight = np.ones((g, g), np.float32)
    near_object = np.zeros((g, g), bool)  # scored although unknown: around an object, its peak's shape
    reg = np.zeros((4, g, g), np.float32)
    reg_w = np.zeros((g, g), np.float32)
    best = np.zeros((g, g), np.float32)  # the Gaussian a cell's regression target belongs to
    lo, hi = cfg.positive_px
    held = np.zeros((g, g), bool)
    for u, v, win, ext, vis, kind in rows:
        dist2 = (centres[None, :] - u) ** 2 + (centres[:, None] - v) ** 2
        if kind == HELD:  # never seen: neither target nor background, wherever it may show
            held |= dist2 <= (0.5 * max(ext, win)) ** 2
            continue
        if vis < 0.1:
            continue  # hidden: background
        positive = lo <= win <= hi and vis >= cfg.min_visib
        near = cfg.ignore_px[0] <= win <= cfg.ignore_px[1]
        if not positive and not near:
            continue  # far out of the head's range: background
        near_object |= dist2 <= (0.75 * win) ** 2
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
    if unknown is not None:
        weight[unknown & ~near_object] = 0.0
    weight[held] = 0.0
    return heat, weight, reg, reg_w
