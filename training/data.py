"""Training data: clean templates, sensor-model renders, real patches; and the network inputs of a batch.

- Objects: the meshes of the BOP datasets given, plus `shapes` procedural objects (`index.shapes`): the
  service registers meshes the network never saw, so it must learn views of objects in general.
- Templates: clean renders at the 301 template viewpoints (in-plane 0, black background), as the index has.
- Synthetic samples: renders from the 1241 training viewpoints with random lighting and a small in-plane
  turn, composited at batch time over a random background, sometimes partly hidden behind another
  object, and passed through the sensor model (`index.sensor`).
- Real samples: patches of annotated BOP instances cut at the true centre, rectified by the true in-plane
  angle plus a small random turn. Most are cut out by their visible mask (rendered from the ground-truth
  pose, nearer objects winning) and pasted on a random background, so the network learns the object and
  not which objects stand next to it in the one scene it saw. Real frames are split into contiguous
  blocks: held-out blocks never reach training, nor do `holdout_gap` frames on either side of them.
Everything rendered is cached under `cache_dir` by a hash of what it depends on.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import trimesh
from tqdm import tqdm

from index.bop import BopDataset, Instance, table_depth
from index.patches import PatchSpec, crop, network_input, patch_camera
from index.pose import View, pose_to_view
from index.render import Lighting, Renderer
from index.sensor import SensorModel, plane_depth, random_background, support_plane, with_support
from index.shapes import random_shape
from index.viewpoints import hemisphere, template_views
from training.similarity import rotations

log = logging.getLogger(__name__)


@dataclass
class DataConfig:
    shapes: int = 40  # procedural objects besides the real meshes (generalisation to unseen meshes)
    shape_views: int = 300  # training renders per procedural object; real meshes get all 1241
    distance: float = 400.0  # render distance, mm (LineMOD's); the metric window makes it matter little
    window_mm: float = 200.0
    inplane_jitter: float = 5.0  # deg, renders and real crops: the rectification is never exact
    centre_jitter_px: float = 1.5  # real crops: the centre is never exact either
    holdout: tuple[tuple[float, float], ...] = ((0.25, 0.40), (0.70, 0.85))  # blocks of each scene's frames
    holdout_gap: int = 2  # frames next to a held-out block also kept out of training (they look alike)
    min_visib_train: float = 0.3  # real instances used for training
    min_visib_test: float = 0.5  # the protocol
    real_paste: float = 0.7  # chance a real patch is cut out by its mask and pasted on a random background
    occlude: float = 0.3  # chance a synthetic sample is partly hidden behind another object
    colour_jitter: float = 0.0  # random gamma / saturation / contrast / hue; off: no gain measured (rgb)
    exclude: tuple[int, ...] = ()  # BOP object ids left out of training, to measure unseen objects
    support: float = 0.5  # chance a synthetic sample stands on a textured support plane (a table)
    clutter: float = 0.6  # chance 1-3 other objects stand around a sample (synthetic or pasted real)
    real_clutter: float = 0.0  # of those, the share cut out of training frames (0.5 measured worse)
    seed: int = 0

    def key(self, roots: list[str]) -> str:
        d = asdict(self)
        batch_time = ("real_paste", "occlude", "min_visib_train", "min_visib_test", "centre_jitter_px")
        for k in (*batch_time, "colour_jitter", "support", "clutter", "real_clutter"):
            d.pop(k)  # batch-time choices: not part of the cache
        # version 2: support planes (per-object z_min; the table in the frames' depth)
        return hashlib.sha1(json.dumps([d, roots, 2], sort_keys=True).encode()).hexdigest()[:12]


@dataclass
class RealInstance:
    frame: int  # index into TrainingData.frames
    obj: int  # object index
    K: np.ndarray
    centre_uv: tuple[float, float]
    view: View  # unrectified: in-plane as annotated
    visib: float
    frame_id: int
    scene: str


def colour_jitter(rgb: np.ndarray, rng: np.random.Generator, strength: float) -> np.ndarray:
    """Random gamma, saturation, contrast and a small hue turn: a mesh's colours, baked under the scanner's
    light, never match what a camera makes of the object. Shape: (S, S, 3) uint8 -> same."""
    if strength <= 0:
        return rgb
    s = strength
    x = (rgb.astype(np.float32) / 255.0) ** rng.uniform(1 - 0.35 * s, 1 + 0.5 * s)
    grey = x.mean(axis=2, keepdims=True)
    x = grey + (x - grey) * rng.uniform(1 - 0.4 * s, 1 + 0.4 * s)
    x = x.mean() + (x - x.mean()) * rng.uniform(1 - 0.25 * s, 1 + 0.25 * s)
    out = np.clip(x * 255.0, 0, 255).astype(np.uint8)
    hsv = cv2.cvtColor(out, cv2.COLOR_RGB2HSV)  # OpenCV's hue is 0-179 (2 degrees a step)
    hsv[..., 0] = ((hsv[..., 0].astype(np.int16) + int(round(rng.uniform(-4, 4) * s))) % 180).astype(np.uint8)
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)


def _random_lighting(rng: np.random.Generator) -> Lighting:
    d = rng.normal(size=3)
    d[2] = abs(d[2]) + 0.5  # from the camera's side
    return Lighting(ambient=float(rng.uniform(0.2, 0.6)), lights=((tuple(d), float(rng.uniform(0.4, 1.0))),))


class TrainingData:
    """All images, in memory. Object indices: the BOP objects first (`real_objects` of them), then shapes."""

    def __init__(self, arrays: dict[str, np.ndarray], meta: dict, cfg: DataConfig):
        self.cfg = cfg
        self.names: list[str] = meta["names"]
        self.symmetries = [
            s if isinstance(s, str) else [np.asarray(m) for m in s] for s in meta["symmetries"]
        ]
        self.real_objects: int = meta["real_objects"]
        self.template_views = [View(*v) for v in meta["template_views"]]
        self.template_R = rotations(self.template_views)
        self.t_rgb, self.t_depth = arrays["t_rgb"], arrays["t_depth"]  # (O, T, S, S, 3), (O, T, S, S)
        self.s_rgb, self.s_depth = arrays["s_rgb"], arrays["s_depth"]  # (M, S, S, 3), (M, S, S)
        self.s_obj, self.s_R = arrays["s_obj"], arrays["s_R"]
        self.z_min: list[float] = meta["z_min"]  # lowest point of each object in its own frame, mm
        self.frames = arrays["frames"]  # (F, H, W, 3) uint8
        self.labels = arrays["labels"]  # (F, H, W) uint8: 1 + object index of the visible object, 0 none
        self.frame_depth = arrays["frame_depth"]  # (F, H, W) float16 mm, rendered from the GT poses
        self.real = [
            RealInstance(
                r["frame"],
                r["obj"],
                np.asarray(r["K"]),
                tuple(r["centre_uv"]),
                View(*r["view"]),
                r["visib"],
                r["frame_id"],
                r["scene"],
            )
            for r in meta["real"]
        ]
        self.real_split = meta["real_split"]  # "train" / "test" / "gap" per instance
        self.heldout_frames: dict[str, list[int]] = meta["heldout_frames"]
        self.spec = PatchSpec(self.t_rgb.shape[2], cfg.window_mm)
        self.sensor = SensorModel()
        self.backgrounds = self._background_tiles(np.random.default_rng(cfg.seed))
        self.train_real = {
            o: [
                i
                for i, r in enumerate(self.real)
                if r.obj == o and self.real_split[i] == "train" and r.visib >= cfg.min_visib_train
            ]
            for o in range(len(self.names))
        }
        self.s_by_obj = {o: np.flatnonzero(self.s_obj == o) for o in range(len(self.names))}
        # real objects of the training frames, to stand around samples as clutter
        self.cutouts = [
            i for i, r in enumerate(self.real) if self.real_split[i] == "train" and r.visib >= 0.5
        ]
        self._template_inputs: dict[str, np.ndarray] = {}

    @property
    def n_objects(self) -> int:
        return len(self.names)

    def test_instances(self, min_visib: float | None = None) -> list[int]:
        v = self.cfg.min_visib_test if min_visib is None else min_visib
        return [i for i, r in enumerate(self.real) if self.real_split[i] == "test" and r.visib >= v]

    def _background_tiles(self, rng: np.random.Generator, n: int = 400) -> list[np.ndarray]:
        """Tiles of the training frames at about an object's scale, for backgrounds."""
        train_frames = sorted({r.frame for i, r in enumerate(self.real) if self.real_split[i] == "train"})
        tiles = []
        for _ in range(n if train_frames else 0):
            f = self.frames[train_frames[rng.integers(len(train_frames))]]
            side = int(rng.integers(100, 240))
            y, x = rng.integers(0, f.shape[0] - side), rng.integers(0, f.shape[1] - side)
            tiles.append(cv2.resize(f[y : y + side, x : x + side], (96, 96), interpolation=cv2.INTER_AREA))
        return tiles

    # --- samples -------------------------------------------------------------------------------------

    def draw(self, obj: int, rng: np.random.Generator, modality: str, real_fraction: float) -> tuple:
        """One training sample of object `obj`: (kind, index, in-plane) and its pose R (3, 3)."""
        real = self.train_real.get(obj, [])
        if real and modality != "depth" and rng.random() < real_fraction:
            i = int(real[rng.integers(len(real))])
            turn = float(rng.uniform(-self.cfg.inplane_jitter, self.cfg.inplane_jitter))
            v = self.real[i].view
            return ("real", i, turn), rotations([View(v.azimuth, v.elevation, turn)])[0]
        i = int(self.s_by_obj[obj][rng.integers(len(self.s_by_obj[obj]))])
        return ("synth", i, 0.0), self.s_R[i]

    def sample_input(self, sample: tuple, modality: str, rng: np.random.Generator) -> np.ndarray:
        kind, i, turn = sample
        if kind == "synth":
            rgb, depth = self._synth(i, rng)
        else:
            rgb, depth = self._real(i, turn, rng)
        return network_input(modality, rgb, depth, self.cfg.distance, self.cfg.window_mm, fill=True)

    def template_inputs(self, modality: str) -> np.ndarray:
        """Every template as the network takes it. Shape: (O, T, C, S, S) float16."""
        if modality not in self._template_inputs:  # templates never change: normalise them once
            self._template_inputs[modality] = np.stack(
                [
                    np.stack([self._template_input(o, k, modality) for k in range(self.t_rgb.shape[1])])
                    for o in range(self.n_objects)
                ]
            ).astype(np.float16)
        return self._template_inputs[modality]

    def template_input(self, obj: int, t: int, modality: str) -> np.ndarray:
        return self.template_inputs(modality)[obj, t].astype(np.float32)

    def _template_input(self, obj: int, t: int, modality: str) -> np.ndarray:
        return network_input(
            modality,
            self.t_rgb[obj, t],
            self.t_depth[obj, t].astype(np.float32),
            self.cfg.distance,
            self.cfg.window_mm,
            fill=False,
        )

    def _background(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        s = self.spec.size
        return random_background((s, s), rng, self.cfg.distance, self.backgrounds)

    def _shifted(self, rng: np.random.Generator, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
        """A random training render moved lo..hi px from the patch centre in a random direction."""
        j = int(rng.integers(len(self.s_rgb)))
        a, r = rng.uniform(0, 2 * np.pi), rng.uniform(lo, hi)
        M = np.float32([[1, 0, r * np.cos(a)], [0, 1, r * np.sin(a)]])
        s = self.spec.size
        o_rgb = cv2.warpAffine(self.s_rgb[j], M, (s, s), flags=cv2.INTER_NEAREST)
        o_depth = cv2.warpAffine(self.s_depth[j].astype(np.float32), M, (s, s), flags=cv2.INTER_NEAREST)
        return o_rgb, o_depth

    def _cutout(self, rng: np.random.Generator, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
        """A real object of a training frame, cut out by its visible mask, moved lo..hi px from the patch
        centre; its depth (rendered from the ground truth) relative to the nominal distance."""
        r = self.real[self.cutouts[int(rng.integers(len(self.cutouts)))]]
        a, dist = rng.uniform(0, 2 * np.pi), rng.uniform(lo, hi)
        shift = dist * np.array([np.cos(a), np.sin(a)])
        f = r.K[0, 0] * self.spec.window_mm / self.spec.size / r.view.distance  # frame px a patch px
        uv = (r.centre_uv[0] - shift[0] * f, r.centre_uv[1] - shift[1] * f)
        turn = float(rng.uniform(-180, 180))
        frame_depth = self.frame_depth[r.frame].astype(np.float32)
        mask = ((self.labels[r.frame] == r.obj + 1) * frame_depth).astype(np.float32)
        rgb, depth = crop(self.frames[r.frame], mask, r.K, uv, r.view.distance, self.spec, turn)
        depth = np.where(depth > 0, depth - r.view.distance + self.cfg.distance, 0.0).astype(np.float32)
        rgb = np.where((depth > 0)[..., None], rgb, 0).astype(np.uint8)
        return rgb, depth

    def _scene(
        self, rng: np.random.Generator, plane: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """What surrounds a sample: a random background, the support plane's depth `plane` (textured like
        another background) when given, and often 1-3 other objects standing around it: real frames are
        cluttered with objects, known ones among them, and the network must learn which one is centred."""
        bg_rgb, bg_depth = self._background(rng)
        if plane is not None:
            bg_depth, bg_rgb = with_support(bg_depth, bg_rgb, plane, self._background(rng)[0])
        if rng.random() < self.cfg.clutter:
            for _ in range(int(rng.integers(1, 4))):
                if self.cutouts and rng.random() < self.cfg.real_clutter:
                    o_rgb, o_depth = self._cutout(rng, 18.0, 46.0)
                else:
                    o_rgb, o_depth = self._shifted(rng, 18.0, 46.0)
                on = o_depth > 0
                bg_rgb = np.where(on[..., None], o_rgb, bg_rgb)
                bg_depth = np.where(on, o_depth + rng.uniform(0.0, 150.0), bg_depth).astype(np.float32)
        return bg_rgb, bg_depth

    def _synth(self, i: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        rgb, depth = self.s_rgb[i].copy(), self.s_depth[i].astype(np.float32)
        if rng.random() < self.cfg.occlude:  # another object in front, shifted towards a side
            o_rgb, o_depth = self._shifted(rng, 28.0, 48.0)
            front = o_depth > 0
            if front.any():
                near = depth[depth > 0].min() if (depth > 0).any() else self.cfg.distance
                o_depth = o_depth - o_depth[front].max() + near - 10.0
                rgb[front], depth[front] = o_rgb[front], o_depth[front]
        rgb = colour_jitter(rgb, rng, self.cfg.colour_jitter)  # the background replaces what is not object
        plane = None
        if rng.random() < self.cfg.support:  # standing on a table
            t = np.array([0.0, 0.0, self.cfg.distance])
            n, d = support_plane(self.s_R[i], t, self.z_min[int(self.s_obj[i])])
            plane = plane_depth(patch_camera(self.spec, self.cfg.distance), n, d, depth.shape)
        bg_rgb, bg_depth = self._scene(rng, plane)
        return self.sensor.apply(rgb, depth, rng, bg_rgb, bg_depth)  # type: ignore[return-value]

    def _real(self, i: int, turn: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        r = self.real[i]
        j = self.cfg.centre_jitter_px
        uv = (r.centre_uv[0] + rng.uniform(-j, j), r.centre_uv[1] + rng.uniform(-j, j))
        d = r.view.distance
        frame_depth = self.frame_depth[r.frame].astype(np.float32)
        rgb, depth = crop(self.frames[r.frame], frame_depth, r.K, uv, d, self.spec, r.view.inplane + turn)
        bg_rgb, bg_depth = self._scene(rng)
        # depth from the rendered frame, relative to the object's own nominal distance like a template's
        depth = np.where(depth > 0, depth - d + self.cfg.distance, 0.0).astype(np.float32)
        if rng.random() < self.cfg.real_paste:
            mask3 = np.repeat(((self.labels[r.frame] == r.obj + 1) * 255).astype(np.uint8)[..., None], 3, 2)
            m = crop(mask3, None, r.K, uv, d, self.spec, r.view.inplane + turn)[0][..., :1] / 255.0
            rgb = (m * rgb + (1 - m) * bg_rgb).astype(np.uint8)
            depth = np.where(m[..., 0] > 0.5, depth, 0.0).astype(np.float32)
        rgb, _ = self.sensor.apply(colour_jitter(rgb, rng, 0.5 * self.cfg.colour_jitter), None, rng)
        _, depth = self.sensor.apply(None, depth, rng, None, bg_depth)
        return rgb, depth  # type: ignore[return-value]


# --- building -----------------------------------------------------------------------------------------


def _split(frame_ids: list[int], cfg: DataConfig) -> dict[int, str]:
    """Contiguous blocks of the frame order held out ("test"), their neighbours ("gap"), the rest "train"."""
    n = len(frame_ids)
    split = {f: "train" for f in frame_ids}
    for a, b in cfg.holdout:
        lo, hi = int(round(a * n)), int(round(b * n))
        for k in range(max(0, lo - cfg.holdout_gap), min(n, hi + cfg.holdout_gap)):
            split[frame_ids[k]] = "test" if lo <= k < hi else "gap"
    return split


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
        np.savez(npz, **arrays)
        js.write_text(json.dumps(meta))
    return TrainingData(arrays, meta, cfg)


def _render_all(roots: list[Path], cfg: DataConfig) -> tuple[dict[str, np.ndarray], dict]:
    rng = np.random.default_rng(cfg.seed)
    renderer = Renderer(window_mm=cfg.window_mm)
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
    t_views = template_views(3, distance=cfg.distance)
    train_vp = hemisphere(4)
    t_rgb, t_depth, s_rgb, s_depth, s_obj, s_R = [], [], [], [], [], []
    for o, mesh in enumerate(tqdm(meshes, desc="render objects", unit="obj", disable=False)):
        t = renderer.render(mesh, t_views)
        t_rgb.append(t.rgb)
        t_depth.append(t.depth.astype(np.float16))
        vps = train_vp if o < real_objects else train_vp[rng.choice(len(train_vp), cfg.shape_views, False)]
        views = [
            View(
                float(az),
                float(el),
                float(rng.uniform(-cfg.inplane_jitter, cfg.inplane_jitter)),
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
    frames, labels, frame_depth, real, real_split, heldout = [], [], [], [], [], {}
    for ds in datasets:
        obj_index = {
            oid: names.index(f"{ds.root.name}/obj_{oid:06d}") for oid in ds.obj_ids if oid not in cfg.exclude
        }

        def meshes_of(oid: int, ds: BopDataset = ds, obj_index: dict = obj_index) -> trimesh.Trimesh:
            return meshes[obj_index[oid]] if oid in obj_index else left_out[(ds.root, oid)]

        for scene in ds.scene_dirs("test") + ds.scene_dirs("train"):
            insts = list(ds.instances(scene))
            frame_ids = sorted({i.frame_id for i in insts})
            split = _split(frame_ids, cfg)
            heldout[f"{ds.root.name}/{scene.name}"] = [f for f in frame_ids if split[f] == "test"]
            by_frame: dict[int, list[Instance]] = {}
            for inst in insts:
                by_frame.setdefault(inst.frame_id, []).append(inst)
            for fid in tqdm(frame_ids, desc=f"masks {scene.name}", unit="frame", disable=False):
                group = by_frame[fid]
                rgb = group[0].load_rgb()
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
                frames.append(rgb)
                labels.append(label)
                table = table_depth(group, [meshes_of(i.obj_id) for i in group], w, h)
                frame_depth.append(np.where(seen, stack.min(axis=0), table).astype(np.float16))
    renderer.close()
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
        "heldout_frames": heldout,
    }
    return arrays, meta


def test_input(data: TrainingData, i: int, modality: str, rng: np.random.Generator) -> np.ndarray:
    """A held-out real instance as the paper's protocol sees it: cut at the true centre and distance,
    rectified by the true in-plane angle. LM-O has no depth: depth is rendered from the ground-truth
    poses of all annotated objects (so they occlude each other), over a random background, through the
    sensor model; the RGB is the real image."""
    r = data.real[i]
    d = r.view.distance
    rgb, depth = crop(
        data.frames[r.frame],
        data.frame_depth[r.frame].astype(np.float32),
        r.K,
        r.centre_uv,
        d,
        data.spec,
        r.view.inplane,
    )
    if modality != "rgb":
        depth = np.where(depth > 0, depth - d + data.cfg.distance, 0.0).astype(np.float32)
        _, bg_depth = data._background(rng)
        _, depth = data.sensor.apply(None, depth, rng, None, bg_depth)
    return network_input(modality, rgb, depth, data.cfg.distance, data.cfg.window_mm, fill=True)
