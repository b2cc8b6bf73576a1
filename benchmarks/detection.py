"""Every registered object found in a whole 640x480 frame (section "detect"): `service.detection.detect`,
what `POST /recognize` runs for a frame sent with its intrinsics and no centre, timed in process.

The state is built as `posedesc serve` builds it (`service.state.load_state` with the service's settings,
`POSEDESC_*` overrides included, the benchmark's models dir as the models dir: the objectness model
`posedesc-objectness.onnx` beside the descriptor models gives the colour proposals), in a temporary data
dir. Objects are registered by the service's own registration (`index.templates.register.register`, the window
following each object's size): the LM-O meshes first, then generated shapes (`index.templates.shapes.random_shape`)
up to each count, `shape_fill` of the model's window across. Each registration's seconds are kept by
window class.

Colour rows: LM-O test frames of scene 2 (real 640x480 PNGs as stored, the camera of
`scene_camera.json`), `frames` of them spread over the scene, each detected `repeats` times after
`warmup` untimed detections (the first reads the meshes that boxes are drawn from). The RGB-D row: the
real Kinect frame (`lmo-depth`, scene 2 frame 3: colour and 16-bit depth), at the smallest count, with
the RGB-D model (depth and colour proposals). Each row gives the p50 / p90 of `timings_ms["total"]`, the
median of every `timings_ms` key (decode, propose, verify, agree, stand, merge, report, mask, total) and how many proposals were verified.
The query is what a user sends: default `max_detections` and floor (a colour proposal scored under the
floor is dropped before it is verified: `service.detection.proposals.Propose`)."""

from __future__ import annotations

import json
import statistics
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from tqdm import tqdm

from benchmarks.timing import ROOT
from index.data.bop import BopDataset
from index.features.embed import MODEL_FILES, fingerprint, load_models
from index.features.objectness import OBJECTNESS_FILE
from index.templates.shapes import random_shape
from index.templates.windows import FILL_HIGH, FILL_LOW, WINDOW_KEY
from service.detection import detect
from service.detection.verify import DEPTH_SHIFT
from service.pipeline import SCREEN_RERANK
from service.pipeline.query import Query
from service.settings import Settings
from service.state import AppState, close_state, load_state

LMO = ROOT.parent / "shared" / "data" / "lmo"
LMO_DEPTH = ROOT.parent / "shared" / "data" / "lmo-depth"
KINECT_FRAME = 3  # the one frame of lmo-depth
#: the service's settings of a detection, reported with the figures (and the stages' constants that steer
#: the screening, under the names their settings had: `DETECT_CONSTANTS`)
DETECT_SETTINGS = ("detect_proposals", "threads", "detect_threads", "objectness_levels")
DETECT_CONSTANTS = {"detect_depth_shift": DEPTH_SHIFT, "detect_screen_rerank": SCREEN_RERANK}


@dataclass(frozen=True)
class DetectConfig:
    # objects registered. 100 is opt-in: 92 registrations beyond the 8 take ~2.8 s each (measured on 2
    # cores at load 4.5, LM-O meshes and generated shapes alike), 4-5 minutes before a frame is asked
    counts: tuple[int, ...] = (8,)
    # colour frames timed, spread over the scene, once each: a frame took ~12 s at load 4 (the detect
    # protocol's 20 validation frames, docs/results/detect-val.json), so three keep the section near 2 min
    frames: int = 3
    repeats: int = 1
    warmup: int = 1  # untimed detections of the first frame before the timed ones, at every count
    rgbd: bool = True  # the RGB-D row, on the Kinect frame at the smallest count
    rgbd_repeats: int = 2
    lmo: Path = LMO
    lmo_depth: Path = LMO_DEPTH
    scene: int = 2
    # The generated shapes' diameters, in the rgb model's windows: the band of its window class
    # (`index.templates.windows`), so every object is seen through LM-O's window. A colour proposal is verified once
    # per window class among the registered objects: shapes 80-300 mm across (random_shape's default) put
    # 18 of 100 in the classes either side of 200 mm, and a frame took 60 proposals and 7.3 s, against 40
    # and 4.3 s at 8 objects, one of them in another class (docs/results/bench-detect-mixed-windows.json)
    shape_fill: tuple[float, float] = (FILL_LOW, FILL_HIGH)


@dataclass(frozen=True)
class Frame:
    """A frame as a user sends it: the files' bytes and the camera."""

    frame_id: int
    rgb: bytes
    depth: bytes | None
    depth_scale: float
    K: np.ndarray

    def query(self) -> Query:
        return Query(
            rgb=self.rgb,
            depth=self.depth,
            depth_scale=self.depth_scale,
            fx=float(self.K[0, 0]),
            fy=float(self.K[1, 1]),
            cx=float(self.K[0, 2]),
            cy=float(self.K[1, 2]),
        )


def run(cfg: DetectConfig, models_dir: Path, level: int = 3, seed: int = 0) -> dict:
    """The section's JSON; without LM-O at `cfg.lmo`, no rows and a note saying so."""
    counts = sorted(set(cfg.counts))
    if not (cfg.lmo / "models" / "models_info.json").is_file():
        note = f"no LM-O at {cfg.lmo}: the detect section needs its meshes and frames; nothing measured"
        return {"by_objects": {}, "register": _registrations([]), "notes": [note], "capped": []}
    dataset = BopDataset(cfg.lmo)
    colour = colour_frames(cfg.lmo / "test" / f"{cfg.scene:06d}", cfg.frames)
    kinect = kinect_frame(cfg.lmo_depth / "test" / f"{cfg.scene:06d}") if cfg.rgbd else None
    embedders = load_models(models_dir, Settings(demo_objects=False).threads)
    wanted = ("rgb", "rgbd") if kinect is not None else ("rgb",)
    embedders = {m: e for m, e in embedders.items() if m in wanted}
    if "rgb" not in embedders:
        raise FileNotFoundError(f"no rgb model: {models_dir / MODEL_FILES['rgb']} is missing")
    objectness = models_dir / OBJECTNESS_FILE
    out: dict = {
        "models": {
            m: {"file": str(e.path), "fingerprint": fingerprint(e.path)} for m, e in embedders.items()
        },
        "objectness": {"file": str(objectness), "fingerprint": fingerprint(objectness)}
        if objectness.is_file()
        else None,
        "frames": {
            "colour": {"dataset": str(cfg.lmo), "scene": cfg.scene, "frames": [f.frame_id for f in colour]},
            "rgbd": None if kinect is None else {"dataset": str(cfg.lmo_depth), "frame": kinect.frame_id},
            "size": "640x480",
        },
        "runs": {"warmup": cfg.warmup, "repeats": cfg.repeats, "rgbd_repeats": cfg.rgbd_repeats},
        "shape_fill": list(cfg.shape_fill),
        "by_objects": {},
        "notes": [],
        "capped": [],
    }
    if kinect is None and cfg.rgbd:
        out["notes"].append(f"no Kinect frame at {cfg.lmo_depth}: the RGB-D row is not measured")
    if "rgbd" not in embedders and kinect is not None:
        out["notes"].append(f"no rgbd model in {models_dir}: the RGB-D row is not measured")
        kinect = None
    with tempfile.TemporaryDirectory(prefix="posedesc-bench-detect-") as tmp:
        settings = Settings(
            data_dir=Path(tmp) / "data", demo_objects=False, models_dir=models_dir, level=level
        )
        out["settings"] = {k: getattr(settings, k) for k in (*DETECT_SETTINGS, "level")} | DETECT_CONSTANTS
        sizes = tuple(f * embedders["rgb"].info.window_mm for f in cfg.shape_fill)
        things = objects(dataset, max(counts), seed, settings.max_faces, (sizes[0], sizes[1]))
        state = load_state(settings, embedders)
        try:
            if state.colour_proposals is None:
                out["notes"].append(
                    f"no {OBJECTNESS_FILE} in {models_dir}: colour frames cannot be searched, colour rows "
                    "are not measured"
                )
            seconds: list[tuple[float, float]] = []  # each registration's window and seconds
            for n in counts:
                t0 = time.perf_counter()
                seconds += _register(state, things[len(seconds) : n])
                snap = state.store.snapshot
                row: dict = {"templates": {m: int(mi.size) for m, mi in snap.models.items()}}
                row["window_classes_mm"] = _classes(state)
                warmup = cfg.warmup  # at each count: the new objects' meshes are read on first use
                if state.colour_proposals is not None:
                    row["colour"] = _time(state, colour, cfg.repeats, warmup, f"detect: {n} objects")
                    warmup = 0
                if kinect is not None and n == counts[0]:
                    row["rgbd"] = _time(state, [kinect], cfg.rgbd_repeats, warmup, f"detect: RGB-D, {n}")
                row["seconds"] = time.perf_counter() - t0  # registering up to n, and the rows at n
                out["by_objects"][str(n)] = row
        finally:
            close_state(state)
    out["objects"] = {
        "lmo": [name for name, _, _ in things if name.startswith("obj_")],
        "generated": sum(not name.startswith("obj_") for name, _, _ in things),
    }
    out["register"] = _registrations(seconds)
    return out


def colour_frames(scene_dir: Path, n: int) -> list[Frame]:
    """`n` colour frames of a BOP scene, spread evenly over its frames, with their cameras."""
    cams = json.loads((scene_dir / "scene_camera.json").read_text())
    ids = sorted(int(p.stem) for p in (scene_dir / "rgb").glob("*.png"))
    if len(ids) < n:
        raise FileNotFoundError(f"{scene_dir / 'rgb'}: {len(ids)} frames, {n} asked for")
    picked = [ids[i * len(ids) // n] for i in range(n)]
    return [
        Frame(f, (scene_dir / "rgb" / f"{f:06d}.png").read_bytes(), None, 1.0, _K(cams[str(f)]))
        for f in picked
    ]


def kinect_frame(scene_dir: Path) -> Frame | None:
    """The real Kinect frame (colour and depth as stored), None where it is absent."""
    rgb, depth = (scene_dir / d / f"{KINECT_FRAME:06d}.png" for d in ("rgb", "depth"))
    if not (rgb.is_file() and depth.is_file()):
        return None
    cam = json.loads((scene_dir / "scene_camera.json").read_text())[str(KINECT_FRAME)]
    return Frame(
        KINECT_FRAME, rgb.read_bytes(), depth.read_bytes(), float(cam.get("depth_scale", 1.0)), _K(cam)
    )


def _K(cam: dict) -> np.ndarray:
    return np.asarray(cam["cam_K"], float).reshape(3, 3)


def objects(
    dataset: BopDataset, n: int, seed: int, max_faces: int, diameter_mm: tuple[float, float]
) -> list[tuple[str, trimesh.Trimesh, str]]:
    """The first `n` objects to register: (name, mesh in mm, symmetry), the dataset's meshes first (loaded
    as `POST /objects` loads a mesh: simplified to `max_faces`), then generated shapes `diameter_mm` across."""
    from evaluation.paper.templates import service_symmetry

    lmo = dataset.obj_ids[:n]
    out = [(f"obj_{o:06d}", dataset.mesh(o, max_faces), service_symmetry(dataset.symmetry(o))) for o in lmo]
    rng = np.random.default_rng(seed)
    return out + [(f"shape_{i}", random_shape(rng, diameter_mm), "none") for i in range(n - len(lmo))]


def _register(state: AppState, todo: Sequence[tuple[str, trimesh.Trimesh, str]]) -> list[tuple[float, float]]:
    """Registers `todo` into the state's store as `POST /objects` does: each one's window and seconds."""
    out = []
    for name, mesh, symmetry in tqdm(todo, desc="detect: register", unit="object", disable=None):
        t0 = time.perf_counter()
        reg = state.register_mesh(mesh, name, symmetry)  # as `POST /objects` registers it
        out.append((float(reg.record.extra[WINDOW_KEY]), time.perf_counter() - t0))  # type: ignore[arg-type]
    return out


def _classes(state: AppState) -> dict[str, int]:
    """How many registered objects each window class (mm) holds."""
    by: dict[str, int] = {}
    for rec in state.store.snapshot.objects.values():
        w = f"{float(rec.extra[WINDOW_KEY]):g}"  # type: ignore[arg-type]  # registered with one
        by[w] = by.get(w, 0) + 1
    return dict(sorted(by.items(), key=lambda kv: float(kv[0])))


def _registrations(seconds: Sequence[tuple[float, float]]) -> dict:
    """Registration seconds, all and by the window the object's size chose."""
    by: dict[float, list[float]] = {}
    for w, s in seconds:
        by.setdefault(w, []).append(s)
    every = [s for _, s in seconds]
    return {
        "objects": len(every),
        "total_s": sum(every),
        "median_s": statistics.median(every) if every else None,
        "by_window_mm": {
            f"{w:g}": {"objects": len(v), "median_s": statistics.median(v), "max_s": max(v)}
            for w, v in sorted(by.items())
        },
    }


def _time(state: AppState, frames: Sequence[Frame], repeats: int, warmup: int, desc: str) -> dict:
    """Every frame detected `repeats` times after `warmup` untimed detections of the first."""
    for _ in range(warmup):
        detect(state, frames[0].query())
    found = []
    with tqdm(total=len(frames) * repeats, desc=desc, unit="frame", disable=None) as bar:
        for f in frames:
            for _ in range(repeats):
                t0 = time.perf_counter()
                r = detect(state, f.query())
                found.append((r, time.perf_counter() - t0))
                bar.update()
    return figures([r.timings_ms for r, _ in found], [r.proposals for r, _ in found],
                   [len(r.detections) for r, _ in found], [s for _, s in found])  # fmt: skip


def figures(
    timings: Sequence[dict[str, float]],
    proposals: Sequence[int],
    detections: Sequence[int],
    wall_s: Sequence[float],
) -> dict:
    """One row: p50 / p90 of the detector's total, the median of every key of its `timings_ms`, the
    proposals verified and the detections reported (each run's, and their medians)."""
    keys = list(dict.fromkeys(k for t in timings for k in t))
    per: dict[str, list[float]] = {k: [t[k] for t in timings if k in t] for k in keys}
    total = np.array(per["total"])
    verify = statistics.median(per["verify"]) if "verify" in per else None
    return {
        "runs": len(timings),
        "p50_ms": float(np.percentile(total, 50)),
        "p90_ms": float(np.percentile(total, 90)),
        "max_ms": float(total.max()),
        "stages_median_ms": {k: statistics.median(v) for k, v in per.items()},
        "wall_p50_ms": float(np.percentile(np.asarray(wall_s) * 1e3, 50)),
        "proposals": list(proposals),
        "proposals_median": statistics.median(proposals),
        "verify_ms_per_proposal": None
        if verify is None or not statistics.median(proposals)
        else verify / statistics.median(proposals),
        "detections": list(detections),
    }
