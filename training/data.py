"""Training data in memory, and the network inputs of a batch (`training/render_cache.py` renders it).

- Objects: the meshes of the BOP datasets given, plus `shapes` procedural objects (`index.templates.shapes`): the
  service registers meshes the network never saw, so it must learn views of objects in general.
- Templates: clean renders at the 301 template viewpoints (black background), each turned in-plane every
  `template_inplane_step` degrees over the whole turn, as the index of a roll-trained model has them: a
  real camera rolls, so a rolled view must be told from a change of view. Kept as one upright render a
  viewpoint, wide enough to turn (`index.templates.render.render_size`), turned when a batch asks for it.
- Synthetic samples: renders from the 1241 training viewpoints with random lighting and a random
  in-plane turn (the whole turn by default), composited at batch time over a random background,
  sometimes partly hidden behind another object, and passed through the sensor model (`index.geometry.sensor`).
- Real samples: patches of annotated BOP instances cut at the true centre, turned to a random in-plane
  angle (the annotated one is undone first). Most are cut out by their visible mask (rendered from the
  ground-truth pose, nearer objects winning) and pasted on a random background, so the network learns
  the object and not which objects stand next to it in the one scene it saw. Real frames are split into
  contiguous blocks (`training/splits.py`): validation and test blocks never reach training, nor do the
  frames beside them. Objects left out (`exclude`) are painted out of every frame.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np
from tqdm import tqdm

from index.features.patches import MODALITY_CHANNELS, PatchSpec, crop, network_input, patch_camera
from index.geometry.pose import View
from index.geometry.sensor import SensorModel, plane_depth, random_background, support_plane, with_support
from index.templates.render import rotate_crop
from training.augment import colour_jitter, soft_edges
from training.similarity import rotations
from training.splits import SplitConfig

log = logging.getLogger(__name__)


@dataclass
class DataConfig:
    shapes: int = 40  # procedural objects besides the real meshes (generalisation to unseen meshes)
    #: more procedural objects, each a single solid of random proportions (`random_shape(n_parts=1)`): boxes
    #: and cans of other sizes, as most household objects are (drawn from their own random stream, so the
    #: data of a config without them is the same as before they existed)
    simple_shapes: int = 0
    shape_views: int = 300  # training renders per procedural object; real meshes get all 1241
    distance: float = 400.0  # render distance, mm (LineMOD's); the metric window makes it matter little
    window_mm: float = 200.0
    roll: float = 180.0  # deg: samples are turned in-plane uniformly within +-roll (180: the whole turn)
    template_inplane_step: float = 30.0  # deg between the in-plane variants of a template (0: upright only)
    size: int = 64  # patch side, px
    centre_jitter_px: float = 1.5  # real crops: the centre is never exact either
    split: SplitConfig = field(default_factory=SplitConfig)  # train / val / test blocks of every scene
    min_visib_train: float = 0.3  # real instances used for training
    min_visib_test: float = 0.5  # the protocol
    real_paste: float = 0.7  # chance a real patch is cut out by its mask and pasted on a random background
    occlude: float = 0.3  # chance a synthetic sample is partly hidden behind another object
    colour_jitter: float = 0.0  # random gamma / saturation / contrast / hue; off: no gain measured (rgb)
    soft_edges: float = 0.0  # chance a synthetic sample's outline is blended (`augment.soft_edges`)
    exclude: tuple[int, ...] = ()  # BOP object ids left out of training, to measure unseen objects
    support: float = 0.5  # chance a synthetic sample stands on a textured support plane (a table)
    clutter: float = 0.6  # chance 1-3 other objects stand around a sample (synthetic or pasted real)
    real_clutter: float = 0.0  # of those, the share cut out of training frames (0.5 measured worse)
    seed: int = 0

    def key(self, roots: list[str]) -> str:
        d = asdict(self)
        batch_time = ("real_paste", "occlude", "min_visib_train", "min_visib_test", "centre_jitter_px")
        for k in (
            *batch_time,
            "colour_jitter",
            "soft_edges",
            "support",
            "clutter",
            "real_clutter",
            "template_inplane_step",
        ):
            d.pop(k)  # batch-time choices: not part of the cache
        if not d["simple_shapes"]:
            d.pop("simple_shapes")  # the caches made before it existed stay valid
        # version 3: templates kept wide (turned at batch time), whole-turn roll, excluded objects painted out
        return hashlib.sha1(json.dumps([d, roots, 3], sort_keys=True).encode()).hexdigest()[:12]


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


class TrainingData:
    """All images, in memory. Object indices: the BOP objects first (`real_objects` of them), then shapes."""

    def __init__(self, arrays: dict[str, np.ndarray], meta: dict, cfg: DataConfig):
        self.cfg = cfg
        self.names: list[str] = meta["names"]
        self.symmetries = [
            s if isinstance(s, str) else [np.asarray(m) for m in s] for s in meta["symmetries"]
        ]
        self.real_objects: int = meta["real_objects"]
        self.viewpoints = [View(*v) for v in meta["template_views"]]  # upright, one a viewpoint
        step = cfg.template_inplane_step
        self.inplane = np.arange(0.0, 360.0, step) if step > 0 else np.zeros(1)
        # template index t = viewpoint * len(inplane) + in-plane variant
        self.template_views = [
            View(v.azimuth, v.elevation, float(a), v.distance) for v in self.viewpoints for a in self.inplane
        ]
        self.template_R = rotations(self.template_views)
        # upright renders wide enough to turn: (O, V, W, W, 3) uint8 and (O, V, W, W) float16 mm
        self.t_rgb, self.t_depth = arrays["t_rgb"], arrays["t_depth"]
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
        self.real_split = meta["real_split"]  # "train" / "val" / "test" / "gap" per instance
        #: {"<dataset>/<scene>": {"train": [...], "val": [...], "test": [...]}}, for the model's metadata
        self.split_frames: dict[str, dict[str, list[int]]] = meta["split_frames"]
        self.spec = PatchSpec(cfg.size, cfg.window_mm)
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

    @property
    def n_templates(self) -> int:
        return len(self.template_views)

    def test_instances(self, split: str = "val", min_visib: float | None = None) -> list[int]:
        """Real instances of the validation (default) or test frames, visible enough to score."""
        v = self.cfg.min_visib_test if min_visib is None else min_visib
        return [i for i, r in enumerate(self.real) if self.real_split[i] == split and r.visib >= v]

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
            roll = float(rng.uniform(-self.cfg.roll, self.cfg.roll))  # the in-plane angle of the patch
            v = self.real[i].view
            return ("real", i, roll), rotations([View(v.azimuth, v.elevation, roll)])[0]
        i = int(self.s_by_obj[obj][rng.integers(len(self.s_by_obj[obj]))])
        return ("synth", i, 0.0), self.s_R[i]

    def sample_input(self, sample: tuple, modality: str, rng: np.random.Generator) -> np.ndarray:
        return self.sample_with_mask(sample, modality, rng)[0]

    def sample_with_mask(
        self, sample: tuple, modality: str, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray]:
        """A sample's network input (C, S, S) and the visible mask (S, S) bool of its centred object."""
        kind, i, roll = sample
        if kind == "synth":
            rgb, depth, mask = self._synth(i, rng)
        else:
            rgb, depth, mask = self._real(i, roll, rng)
        x = network_input(modality, rgb, depth, self.cfg.distance, self.cfg.window_mm, fill=True)
        return x, mask

    def template_inputs(self, modality: str) -> np.ndarray:
        """Every template (in-plane variants included) as the network takes it. Shape: (O, T, C, S, S)
        float16 (~2 GB for 47 objects x 3612 colour templates)."""
        if modality not in self._template_inputs:  # templates never change: turn and normalise them once
            out = np.zeros(
                (
                    self.n_objects,
                    self.n_templates,
                    MODALITY_CHANNELS[modality],
                    self.spec.size,
                    self.spec.size,
                ),
                np.float16,
            )
            for o in tqdm(range(self.n_objects), desc="template inputs", unit="obj", leave=False):
                for k in range(self.n_templates):
                    out[o, k] = self._template_input(o, k, modality)
            self._template_inputs[modality] = out
        return self._template_inputs[modality]

    def drop_template_inputs(self, modality: str) -> None:
        """Frees the normalised templates (they are made again when asked for)."""
        self._template_inputs.pop(modality, None)

    def template_input(self, obj: int, t: int, modality: str) -> np.ndarray:
        return self.template_inputs(modality)[obj, t].astype(np.float32)

    def template_patch(self, obj: int, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Template t of an object, turned to its in-plane angle: rgb (S, S, 3), depth (S, S) mm."""
        v, k = divmod(t, len(self.inplane))
        return rotate_crop(
            self.t_rgb[obj, v],
            self.t_depth[obj, v].astype(np.float32),
            float(self.inplane[k]),
            self.spec.size,
        )

    def _template_input(self, obj: int, t: int, modality: str) -> np.ndarray:
        rgb, depth = self.template_patch(obj, t)
        return network_input(
            modality,
            rgb,
            depth,
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
        M: np.ndarray = np.float32([[1, 0, r * np.cos(a)], [0, 1, r * np.sin(a)]])  # type: ignore[arg-type, assignment]  # numpy's stub: np.float32(list) is an array
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

    def _synth(self, i: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rgb, depth = self.s_rgb[i].copy(), self.s_depth[i].astype(np.float32)
        mask = depth > 0
        if rng.random() < self.cfg.occlude:  # another object in front, shifted towards a side
            o_rgb, o_depth = self._shifted(rng, 28.0, 48.0)
            front = o_depth > 0
            if front.any():
                near = depth[depth > 0].min() if (depth > 0).any() else self.cfg.distance
                o_depth = o_depth - o_depth[front].max() + near - 10.0
                rgb[front], depth[front] = o_rgb[front], o_depth[front]
                mask &= ~front
        rgb = colour_jitter(rgb, rng, self.cfg.colour_jitter)  # the background replaces what is not object
        plane = None
        if rng.random() < self.cfg.support:  # standing on a table
            t = np.array([0.0, 0.0, self.cfg.distance])
            n, d = support_plane(self.s_R[i], t, self.z_min[int(self.s_obj[i])])
            plane = plane_depth(patch_camera(self.spec, self.cfg.distance), n, d, depth.shape)
        bg_rgb, bg_depth = self._scene(rng, plane)
        behind: np.ndarray | None = bg_rgb
        # the edge blended here, and the sensor composites nothing more (no draw when off: runs repeat)
        if self.cfg.soft_edges > 0 and rng.random() < self.cfg.soft_edges:
            rgb, behind = soft_edges(rgb, bg_rgb, depth > 0, rng), None
        rgb, depth = self.sensor.apply(rgb, depth, rng, behind, bg_depth)
        return rgb, depth, mask

    def _real(
        self, i: int, roll: float, rng: np.random.Generator
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Real instance i cut so that it appears turned `roll` degrees in-plane, with its visible mask."""
        r = self.real[i]
        j = self.cfg.centre_jitter_px
        uv = (r.centre_uv[0] + rng.uniform(-j, j), r.centre_uv[1] + rng.uniform(-j, j))
        d = r.view.distance
        frame_depth = self.frame_depth[r.frame].astype(np.float32)
        undo = r.view.inplane - roll  # crop undoes this angle: the object comes out rolled by `roll`
        rgb, depth = crop(self.frames[r.frame], frame_depth, r.K, uv, d, self.spec, undo)
        bg_rgb, bg_depth = self._scene(rng)
        # depth from the rendered frame, relative to the object's own nominal distance like a template's
        depth = np.where(depth > 0, depth - d + self.cfg.distance, 0.0).astype(np.float32)
        mask3 = np.repeat(((self.labels[r.frame] == r.obj + 1) * 255).astype(np.uint8)[..., None], 3, 2)
        m = crop(mask3, None, r.K, uv, d, self.spec, undo)[0][..., :1] / 255.0
        if rng.random() < self.cfg.real_paste:
            rgb = (m * rgb + (1 - m) * bg_rgb).astype(np.uint8)
            depth = np.where(m[..., 0] > 0.5, depth, 0.0).astype(np.float32)
        rgb, _ = self.sensor.apply(colour_jitter(rgb, rng, 0.5 * self.cfg.colour_jitter), None, rng)
        _, depth = self.sensor.apply(None, depth, rng, None, bg_depth)
        return rgb, depth, m[..., 0] > 0.5


def test_input(
    data: TrainingData, i: int, modality: str, rng: np.random.Generator, rectify: bool = False
) -> np.ndarray:
    """A held-out real instance as a user sends it: cut at the true centre and distance, rolled as the
    camera saw it (`rectify`: the paper's protocol, the true in-plane angle undone). LM-O has no depth: depth is rendered from the ground-truth
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
        r.view.inplane if rectify else 0.0,
    )
    if modality != "rgb":
        depth = np.where(depth > 0, depth - d + data.cfg.distance, 0.0).astype(np.float32)
        _, bg_depth = data._background(rng)
        _, depth = data.sensor.apply(None, depth, rng, None, bg_depth)
    return network_input(modality, rgb, depth, data.cfg.distance, data.cfg.window_mm, fill=True)
