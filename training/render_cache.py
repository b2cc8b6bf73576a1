"""Rendering everything training needs, once, and the cache that keeps it.

`build` returns the `TrainingData` of some BOP datasets and a `DataConfig`: clean templates of every
object (upright and wide enough to turn), training renders of the BOP meshes (all 1241 training
viewpoints) and of the procedural shapes, and for every real frame its objects' visible masks and
depth rendered from the ground truth (LM-O has no depth). Everything is cached under `cache_dir` by a
hash of what it depends on (`DataConfig.key`), so a second run with the same data starts at once.
Objects left out of training (`exclude`) still occlude in the masks, but are painted out of the frames.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import cv2
import numpy as np
import trimesh
from tqdm import tqdm

from index.data.bop import BopDataset, Instance, table_depth
from index.geometry.pose import View, pose_to_view
from index.templates.render import Lighting, Renderer, render_size
from index.templates.shapes import random_shape
from index.templates.viewpoints import hemisphere, sphere_views
from training.data import DataConfig, TrainingData
from training.similarity import rotations
from training.splits import frames_of, split_frames

log = logging.getLogger(__name__)


def _random_lighting(rng: np.random.Generator) -> Lighting:
    d = rng.normal(size=3)
    d[2] = abs(d[2]) + 0.5  # from the camera's side
    return Lighting(ambient=float(rng.uniform(0.2, 0.6)), lights=((tuple(d), float(rng.uniform(0.4, 1.0))),))


def build(roots: list[Path], cfg: DataConfig, cache_dir: Path | None = None) -> TrainingData:
    """Renders (or loads from the cache) everything `TrainingData` holds."""
    key = cfg.key([str(Path(r).resolve()) for r in roots])
    if cache_dir is not None:
        npz, js = cache_dir / f"data-{key}.npz", cache_dir / f"data-{key}.json"
        if npz.is_file() and js.is_file():
            log.info("training data from cache %s", npz)
            with np.load(npz) as z:
                arrays = {k: z[k] for k in z.files}
            return TrainingData(arrays, json.loads(js.read_text()), cfg)
    arrays, meta = _render_all(roots, cfg)
    if cache_dir is not None:
        cache_dir.mkdir(parents=True, exist_ok=True)
        np.savez(npz, **arrays)  # type: ignore[arg-type]  # numpy's stub: a key could be allow_pickle
        js.write_text(json.dumps(meta))
    return TrainingData(arrays, meta, cfg)


def _render_all(roots: list[Path], cfg: DataConfig) -> tuple[dict[str, np.ndarray], dict]:
    rng = np.random.default_rng(cfg.seed)
    renderer = Renderer(size=cfg.size, window_mm=cfg.window_mm)
    # templates are kept upright and wide enough to turn: the same pixel scale, a wider window
    wide = render_size(cfg.size)
    wide_renderer = Renderer(size=wide, window_mm=cfg.window_mm * wide / cfg.size)
    meshes, names, symmetries = [], [], []
    datasets = [BopDataset(r) for r in roots]
    left_out = {}  # rendered into the frames' masks and depth (they occlude), never a training object
    for ds in datasets:
        for o in ds.obj_ids:
            if o in cfg.exclude:
                left_out[(ds.root, o)] = ds.mesh(o, max_faces=20000)
                continue
            meshes.append(ds.mesh(o, max_faces=20000))
            names.append(f"{ds.root.name}/obj_{o:06d}")
            sym = ds.symmetry(o)
            symmetries.append(sym if isinstance(sym, str) else [np.asarray(m).tolist() for m in sym])
    real_objects = len(meshes)
    for k in range(cfg.shapes):
        meshes.append(random_shape(rng))
        names.append(f"shape_{k:03d}")
        symmetries.append("none")
    simple = np.random.default_rng([cfg.seed, 1])  # their own stream: the rest is drawn as without them
    for k in range(cfg.simple_shapes):
        meshes.append(random_shape(simple, n_parts=1))
        names.append(f"solid_{k:03d}")
        symmetries.append("none")
    t_views = sphere_views(3, distance=cfg.distance)
    train_vp = hemisphere(4)
    t_rgb, t_depth, s_rgb, s_depth, s_obj, s_R = [], [], [], [], [], []
    for o, mesh in enumerate(tqdm(meshes, desc="render objects", unit="obj", disable=False)):
        t = wide_renderer.render(mesh, t_views)
        t_rgb.append(t.rgb)
        t_depth.append(t.depth.astype(np.float16))
        vps = train_vp if o < real_objects else train_vp[rng.choice(len(train_vp), cfg.shape_views, False)]
        views = [
            View(
                float(az),
                float(el),
                float(rng.uniform(-cfg.roll, cfg.roll)),
                cfg.distance,
            )
            for az, el in vps
        ]
        for c in range(0, len(views), 64):  # a random lighting per chunk
            chunk = views[c : c + 64]
            r = renderer.render(mesh, chunk, lighting=_random_lighting(rng))
            s_rgb.append(r.rgb)
            s_depth.append(r.depth.astype(np.float16))
            s_obj += [o] * len(chunk)
            s_R.append(rotations(chunk))
    frames: list[np.ndarray]
    frames, labels, frame_depth, real, real_split, splits = [], [], [], [], [], {}
    for ds in datasets:
        obj_index = {
            oid: names.index(f"{ds.root.name}/obj_{oid:06d}") for oid in ds.obj_ids if oid not in cfg.exclude
        }

        def meshes_of(oid: int, ds: BopDataset = ds, obj_index: dict = obj_index) -> trimesh.Trimesh:
            return meshes[obj_index[oid]] if oid in obj_index else left_out[(ds.root, oid)]

        for scene in ds.scene_dirs("test") + ds.scene_dirs("train"):
            insts = list(ds.instances(scene))
            frame_ids = sorted({i.frame_id for i in insts})
            split = split_frames(frame_ids, cfg.split)
            splits[f"{ds.root.name}/{scene.name}"] = frames_of(split)
            by_frame: dict[int, list[Instance]] = {}
            for inst in insts:
                by_frame.setdefault(inst.frame_id, []).append(inst)
            for fid in tqdm(frame_ids, desc=f"masks {scene.name}", unit="frame", disable=False):
                group = by_frame[fid]
                rgb: np.ndarray = group[0].load_rgb()  # type: ignore[assignment]  # BOP frames have images
                h, w = rgb.shape[:2]
                depths = []
                for inst in group:
                    mesh = meshes_of(inst.obj_id)
                    _, d = renderer.render_frame([(mesh, inst.R, inst.t)], inst.K, w, h)
                    depths.append(np.where(d > 0, d, np.inf))
                stack = np.stack(depths)
                nearest = np.argmin(stack, axis=0)
                label = np.zeros((h, w), np.uint8)
                seen = np.isfinite(stack.min(axis=0))
                for k, inst in enumerate(group):
                    if inst.obj_id not in obj_index:
                        continue
                    label[seen & (nearest == k)] = obj_index[inst.obj_id] + 1
                    v = pose_to_view(inst.R, inst.t)
                    real.append(
                        {
                            "frame": len(frames),
                            "obj": obj_index[inst.obj_id],
                            "K": inst.K.tolist(),
                            "centre_uv": list(inst.centre_uv),
                            "view": [v.azimuth, v.elevation, v.inplane, v.distance],
                            "visib": inst.visib_fract,
                            "frame_id": fid,
                            "scene": scene.name,
                        }
                    )
                    real_split.append(split[fid])
                table = table_depth(group, [meshes_of(i.obj_id) for i in group], w, h)
                hidden = np.zeros((h, w), bool)  # pixels of objects left out of training
                for k, inst in enumerate(group):
                    if inst.obj_id not in obj_index:
                        hidden |= seen & (nearest == k)
                if hidden.any():
                    rgb = paint_out(rgb, hidden)
                frames.append(rgb)
                labels.append(label)
                frame_depth.append(np.where(seen & ~hidden, stack.min(axis=0), table).astype(np.float16))
    renderer.close()
    wide_renderer.close()
    s = t_rgb[0].shape[1]
    arrays = {
        "t_rgb": np.stack(t_rgb),
        "t_depth": np.stack(t_depth),
        "s_rgb": np.concatenate(s_rgb),
        "s_depth": np.concatenate(s_depth),
        "s_obj": np.array(s_obj, np.int64),
        "s_R": np.concatenate(s_R),
        "frames": np.stack(frames) if frames else np.zeros((0, s, s, 3), np.uint8),
        "labels": np.stack(labels) if labels else np.zeros((0, s, s), np.uint8),
        "frame_depth": np.stack(frame_depth) if frame_depth else np.zeros((0, s, s), np.float16),
    }
    meta = {
        "z_min": [float(m.bounds[0][2]) for m in meshes],
        "names": names,
        "symmetries": symmetries,
        "real_objects": real_objects,
        "template_views": [[v.azimuth, v.elevation, v.inplane, v.distance] for v in t_views],
        "real": real,
        "real_split": real_split,
        "split_frames": splits,
    }
    return arrays, meta


def paint_out(rgb: np.ndarray, mask: np.ndarray, grow_px: int = 4) -> np.ndarray:
    """The frame with the pixels of `mask` (grown by `grow_px`, for the blurred edge) inpainted from their
    surroundings (Telea): an object left out of training leaves no pixel behind. Shape: (H, W, 3) uint8."""
    kernel = np.ones((2 * grow_px + 1, 2 * grow_px + 1), np.uint8)
    m = cv2.dilate(mask.astype(np.uint8), kernel)
    return cv2.inpaint(np.ascontiguousarray(rgb), m, 5, cv2.INPAINT_TELEA)
