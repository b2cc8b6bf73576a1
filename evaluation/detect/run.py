"""The detect protocol (`posedesc evaluate --protocol detect`): every frame sent whole, with its
intrinsics only, to the service's detector (`service.detection.detect`, what `POST /recognize` runs for a
frame without u and v), and OpenCV's LineMOD over a frame pyramid beside it (`evaluation.baselines.linemod_frames`),
both scored by `evaluation.detect.score`.

The objects are registered as the service protocol registers them (`evaluation.served.register_objects`:
the service's own registration into a real store in a temporary folder, with the service's settings).
Frames are those of `frames` holding an annotated instance of a registered object; they are sent as a user
sends them (`evaluation.queries.frame_files`: the dataset's own image files; rendered depth where a depth
model meets a dataset without depth). Every instance of a registered object is ground truth; those less
than half visible are neither targets nor errors (`evaluation.detect.score`).

Each frame is asked once with the floor at 0 and room for `ALL` detections: the ranking AP50 is
measured on (its `max_detections` most confident); the figures at the floor are the same answers with
the floor applied as the detector applies it (`service.detection.reported`), then cut to
`max_detections`, which is what a call with that floor returns.

The service's reported detections are also scored the BOP way (the JSON's "bop" block,
`evaluation.bop.scores.detections_block`: targets at least 0.1 visible, MSSD, MSPD, AR) and returned as
BOP19 results rows (`bop_estimates`, what `--bop-csv` writes).

False alarms: the same frames with only objects that are not in them registered (the service's four demo
shapes, `index.templates.shapes.demo_shapes`, and `GENERATED` shapes of `index.templates.shapes.random_shape`): each detection
the service reports at the floor is false; so is each of LineMOD's, with templates of those shapes."""

from __future__ import annotations

import tempfile
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
import trimesh

from evaluation.baselines.linemod_frames import (
    CANDIDATE_SIMILARITY,
    FEATURES,
    NMS_IOU,
    SMALLEST_WINDOW_PX,
    WINDOW_STEP,
    LineModFrames,
    window_sizes,
)
from evaluation.bop.csv import Estimate
from evaluation.bop.scores import BOP_MIN_VISIB, detections_block, object_model
from evaluation.bop.vsd import vsd_for
from evaluation.detect.cues import cue_outcomes, cues_of
from evaluation.detect.score import IOU, MIN_VISIB, ROTATION_OK_DEG, Hit, Truth, match, scores
from evaluation.paper.samples import RENDERED, select_instances, served_data
from evaluation.paper.templates import service_symmetry
from evaluation.progress import bar
from evaluation.queries import frame_files
from evaluation.served import register_objects, served_models
from index.data.bop import BopDataset, Instance
from index.features.embed import Embedder, fingerprint
from index.templates.register import template_views
from index.templates.render import Renderer
from index.templates.shapes import demo_shapes, random_shape
from service.detection import Detection, detect, floors, reported
from service.errors import ApiError
from service.pipeline.context import Query
from service.settings import Settings
from service.state import AppState, close_state, load_state, objectness_path

ALL = 100  # detections asked for per frame: every one the detector keeps (a frame of LM-O holds 7 objects)
GENERATED = 3  # generated shapes beside the 4 demo shapes: as many unknown objects as LM-O has objects


@dataclass(frozen=True)
class DetectConfig:
    dataset: Path
    model: Path
    scene: int = 2
    frames: Sequence[int] | None = None  # None: every frame of the scene
    objects: Sequence[int] | None = None  # None: every object of the dataset
    max_detections: int = 10
    min_confidence: float | None = None  # None: the model's open-set verdict
    linemod: bool = False
    false_alarms: bool = False
    smallest_window_px: float = SMALLEST_WINDOW_PX  # LineMOD's pyramid
    window_step: float = WINDOW_STEP
    seed: int = 0


@dataclass(frozen=True)
class Frame:
    key: tuple[int, int]
    instances: list[Instance]
    rgb: bytes | None
    depth: bytes | None
    depth_scale: float

    @property
    def K(self) -> np.ndarray:
        return self.instances[0].K


@dataclass(frozen=True)
class Asked:
    """One detector's answers: each frame's detections at floor 0 (`ranked`, most confident first,
    `max_detections` of them), at the floor asked for (`floor`), and each frame's milliseconds."""

    ranked: list[Hit]
    floor: list[Hit]
    frame_ms: list[float]
    stage_ms: dict[str, list[float]]
    #: per hit of `ranked` (the same order), what a calibrated confidence reads (`cues_of`); none for LineMOD
    cues: list[dict] = field(default_factory=list)


def evaluate_detect(cfg: DetectConfig) -> tuple[dict, list[Estimate]]:
    """The JSON of the detect protocol (see the module's docstring) and the service's reported detections
    as BOP19 results rows (`bop_estimates`)."""
    dataset = BopDataset(cfg.dataset)
    obj_ids = list(cfg.objects) if cfg.objects else dataset.obj_ids
    instances = select_instances(dataset, cfg.scene, 0.0, cfg.frames, obj_ids)
    if not instances:
        raise ValueError(
            f"{cfg.dataset}: no instance of scene {cfg.scene} in the frames and objects asked for"
        )
    truths = [Truth.of(i) for i in instances]
    symmetries = {o: dataset.symmetry(o) for o in obj_ids}
    seconds: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="posedesc-detect-") as tmp:
        settings = service_settings(cfg.model, Path(tmp) / "objects")
        objectness = objectness_path(settings)
        embedder = Embedder(cfg.model, settings.threads)  # as the service loads it
        kind = served_data(embedder.modality, instances, None)
        state = load_state(settings, served_models(embedder, settings.threads))
        try:
            t0 = time.perf_counter()
            meshes, dataset_ids = register_objects(state, dataset, obj_ids)
            seconds["register"] = time.perf_counter() - t0
            frames = _frames(
                dataset, instances, embedder.modality, kind, cfg.seed, meshes, settings.max_faces
            )
            t0 = time.perf_counter()
            ours = ask_service(state, frames, dataset_ids, cfg)
            seconds["posedesc"] = time.perf_counter() - t0
            views = _views(state, embedder, {o: service_symmetry(symmetries[o]) for o in obj_ids})
        finally:
            close_state(state)
        out: dict = {"posedesc": _figures(ours, truths, symmetries, len(frames))}
        out["posedesc"]["cues"] = cue_outcomes(ours.ranked, ours.cues, truths)
        rows = bop_estimates(ours, frames)
        out["bop"] = _bop(dataset, instances, rows, _frame_size(frames[0])[1], kind)
        n_templates = sum(map(len, views.values()))
        if cfg.linemod:
            t0 = time.perf_counter()
            lm = linemod_detector(meshes, views, embedder)
            seconds["linemod_templates"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            out["linemod"] = _figures(ask_linemod(lm, frames, cfg), truths, symmetries, len(frames))
            out["linemod"]["templates"] = {"added": len(lm), "without_enough_features": lm.index.skipped}
            seconds["linemod"] = time.perf_counter() - t0
        if cfg.false_alarms:
            t0 = time.perf_counter()
            out["false_alarms"] = false_alarms(cfg, Path(tmp) / "unknown", embedder, frames)
            seconds["false_alarms"] = time.perf_counter() - t0
    h, w = _frame_size(frames[0])
    summary: dict = {
        "protocol": "detect",
        "dataset": str(cfg.dataset),
        "scene": cfg.scene,
        "frames": sorted(f.key[1] for f in frames),
        "objects": obj_ids,
        "model": str(cfg.model),
        "modality": embedder.modality,
        "objectness": {"file": str(objectness), "fingerprint": fingerprint(objectness)}
        if objectness.is_file() and embedder.modality != "depth"
        else None,
        "test_data": kind,
        "targets": sum(t.target for t in truths),
        "settings": {
            "max_detections": cfg.max_detections,
            "min_confidence": cfg.min_confidence,
            "floor": "the detector's default (service.detection.reported)"
            if cfg.min_confidence is None
            else "confidence",
            "iou": IOU,
            "min_visib": MIN_VISIB,
            "bop_min_visib": BOP_MIN_VISIB,
            "rotation_within_deg": ROTATION_OK_DEG,
            "ap": "AP50: one ranking pooled over frames and objects (floor 0, max_detections a frame), "
            "all-point interpolation (VOC 2010+)",
            "n_templates": n_templates,
        },
        **out,
        "seconds": {k: round(v, 1) for k, v in seconds.items()},
    }
    if cfg.linemod:
        summary["settings"]["linemod"] = {
            "windows_px": [round(float(x), 1) for x in window_sizes(min(h, w), cfg.smallest_window_px,
                                                                    cfg.window_step)],
            "candidate_similarity": CANDIDATE_SIMILARITY,
            "nms_iou": NMS_IOU,
            "features": {"colour": FEATURES[0], "depth": FEATURES[1]},
            "templates": "the service's template views of each object (viewpoints and in-plane variants), "
            "rendered by the service's renderer, one LineMOD class each",
        }  # fmt: skip
    return summary, rows


def bop_estimates(asked: Asked, frames: Sequence[Frame]) -> list[Estimate]:
    """The detections reported at the floor as BOP19 results rows: obj_id the dataset's id of the object
    of the detection's best answer, score its confidence, R and t that answer's pose, time the frame's
    seconds (BOP's: the whole image's, the same on each of its rows)."""
    seconds = {f.key: ms / 1000 for f, ms in zip(frames, asked.frame_ms, strict=True)}
    return [
        Estimate(h.frame[0], h.frame[1], h.obj_id, h.score, h.R, h.t, seconds[h.frame])
        for h in asked.floor
        if h.R is not None and h.t is not None and h.obj_id >= 0
    ]


def _bop(
    dataset: BopDataset, instances: Sequence[Instance], rows: Sequence[Estimate], width: int, sent: str
) -> dict:
    """The JSON's "bop" block (`evaluation.bop.scores.detections_block`): models from the full meshes and
    models_info; VSD where the frames sent have recorded depth (`sent`: `served_data`'s kind)."""
    meshes = {o: dataset.mesh(o) for o in {i.obj_id for i in instances}}
    models = {o: object_model(dataset.symmetry_info(o), m) for o, m in meshes.items()}
    vsd = vsd_for(instances, meshes, {o: m.diameter for o, m in models.items()}, sent)
    try:
        block = detections_block(instances, rows, models, width, vsd)
    finally:
        if vsd is not None:
            vsd.close()
    return {
        **block,
        "estimates": "the detections reported at the floor (the --bop-csv rows): the dataset's object of "
        "each one's best answer, its confidence as the score, that answer's pose",
    }


def service_settings(model: Path, data_dir: Path) -> Settings:
    """The service's settings (`POSEDESC_*`) with a fresh `data_dir`, no demo objects, and the model's
    folder as the models dir: the objectness model that makes colour proposals sits beside the
    descriptor model (`index.features.objectness.OBJECTNESS_FILE`)."""
    return Settings(data_dir=data_dir, demo_objects=False, models_dir=model.parent)


def _frames(
    dataset: BopDataset,
    instances: Sequence[Instance],
    modality: str,
    kind: str,
    seed: int,
    meshes: Mapping[int, trimesh.Trimesh],
    max_faces: int,
) -> list[Frame]:
    """Every frame's files as a user sends them (`evaluation.queries.frame_files`), read once."""
    renderer = Renderer() if kind in RENDERED else None  # this thread's (EGL: a context a thread)
    try:
        return [
            Frame((g[0].scene_id, g[0].frame_id), g, rgb, depth, scale)
            for g, rgb, depth, scale in frame_files(
                dataset, instances, modality, kind, seed, renderer, dict(meshes), max_faces
            )
        ]
    finally:
        if renderer is not None:
            renderer.close()


def _frame_size(frame: Frame) -> tuple[int, int]:
    rgb, depth = decoded(frame)
    image = rgb if rgb is not None else depth
    if image is None:
        raise ValueError(f"frame {frame.key}: nothing to send")
    return int(image.shape[0]), int(image.shape[1])


def frame_query(frame: Frame) -> Query:
    """What a user sends to find the objects of a frame: the frame and the camera, no centre."""
    K = frame.K
    return Query(
        rgb=frame.rgb,
        depth=frame.depth,
        depth_scale=frame.depth_scale,
        fx=K[0, 0],
        fy=K[1, 1],
        cx=K[0, 2],
        cy=K[1, 2],
    )


def ask_service(
    state: AppState, frames: Sequence[Frame], dataset_ids: Mapping[int, int], cfg: DetectConfig
) -> Asked:
    """Every frame through the service's detector (floor 0, `ALL` detections); see the module's docstring."""
    ranked: list[Hit] = []
    floor: list[Hit] = []
    cues: list[dict] = []
    frame_ms: list[float] = []
    stage_ms: dict[str, list[float]] = {}
    with bar(len(frames), "detect (posedesc)", "frame") as b:
        for frame in frames:
            q = replace(frame_query(frame), max_detections=ALL, min_confidence=0.0)
            t0 = time.perf_counter()
            try:
                found = detect(state, q)
            except ApiError as e:  # e.g. a colour frame and no objectness model beside the model
                raise ValueError(f"the service refused frame {frame.key[1]}: {e.detail}") from None
            frame_ms.append(1000 * (time.perf_counter() - t0))
            for k, v in found.timings_ms.items():
                stage_ms.setdefault(k, []).append(v)
            hits = [(d, _hit(frame.key, d, dataset_ids)) for d in found.detections]
            ranked += [h for _, h in hits[: cfg.max_detections]]
            cues += [cues_of(d) for d, _ in hits[: cfg.max_detections]]
            at = floors(state.settings, frame.depth is not None)
            at_floor = [h for d, h in hits if reported(d, cfg.min_confidence, at)]
            floor += at_floor[: cfg.max_detections]
            b.update()
    return Asked(ranked, floor, frame_ms, stage_ms, cues)


def _hit(frame: tuple[int, int], d: Detection, dataset_ids: Mapping[int, int]) -> Hit:
    """A `service.detection.Detection` as a hit: its best answer's object (dataset id) and pose."""
    best = d.result.matches[0]
    R, t = d.result.pose(0)
    return Hit(frame, dataset_ids.get(best.object_id, -1), float(d.confidence), d.box, R, t)


def _views(state: AppState, embedder: Embedder, symmetries: Mapping[int, str]) -> dict:
    """Each object's template views as the service registers them for the model."""
    step = embedder.info.inplane_step
    return {o: template_views(s, state.templates, step) for o, s in symmetries.items()}


def linemod_detector(
    meshes: Mapping[int, trimesh.Trimesh], views: Mapping, embedder: Embedder
) -> LineModFrames:
    """LineMOD templates of every object: its `views`, rendered by the service's renderer."""
    spec = embedder.info.spec
    lm = LineModFrames(embedder.modality, spec.window_mm, spec.size)
    renderer = Renderer(size=spec.size, window_mm=spec.window_mm)
    try:
        with bar(sum(map(len, views.values())), "LineMOD templates", "template") as b:
            for o, mesh in meshes.items():
                lm.add(o, renderer.render(mesh, views[o]), progress=b.update)
    finally:
        renderer.close()
    return lm


def ask_linemod(lm: LineModFrames, frames: Sequence[Frame], cfg: DetectConfig) -> Asked:
    """Every frame through LineMOD (`LineModFrames.detect`); all it reports is at its floor."""
    hits: list[Hit] = []
    frame_ms: list[float] = []
    with bar(len(frames), "detect (LineMOD)", "frame") as b:
        for frame in frames:
            t0 = time.perf_counter()
            rgb, depth = decoded(frame)
            short = min((rgb if rgb is not None else depth).shape[:2])  # type: ignore[union-attr]  # one is sent
            windows = window_sizes(short, cfg.smallest_window_px, cfg.window_step)
            hits += lm.detect(frame.key, rgb, depth, frame.K, windows, cfg.max_detections)
            frame_ms.append(1000 * (time.perf_counter() - t0))
            b.update()
    return Asked(hits, hits, frame_ms, {})


def decoded(frame: Frame) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The frame's colour (RGB) and depth (mm) images from the files sent."""
    rgb = depth = None
    if frame.rgb is not None:
        rgb = _image(frame.rgb, cv2.IMREAD_COLOR)[..., ::-1]
    if frame.depth is not None:
        depth = _image(frame.depth, cv2.IMREAD_UNCHANGED).astype(np.float32) * frame.depth_scale
    return rgb, depth


def _image(data: bytes, flags: int) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if image is None:
        raise ValueError("a frame's file cannot be decoded")
    return image


def _figures(asked: Asked, truths: Sequence[Truth], symmetries: Mapping, n_frames: int) -> dict:
    """A detector's figures: at the floor, and AP50 of the ranking; frame times."""
    at = scores(match(asked.floor, truths), symmetries)
    ranked = scores(match(asked.ranked, truths), symmetries)
    for block, of in [(at["all"], ranked["all"])] + [
        (at["per_object"][o], ranked["per_object"][o]) for o in at["per_object"]
    ]:
        block["ap50"] = of["ap50"]  # the ranking's, not the floor's truncated one
    ms = np.array(asked.frame_ms)
    return {
        **at,
        "detections_per_frame": round(len(asked.floor) / max(n_frames, 1), 3),
        "frame_ms": {"median": round(float(np.median(ms)), 1), "p90": round(float(np.percentile(ms, 90)), 1)},
        **(
            {"stage_ms_median": {k: round(float(np.median(v)), 1) for k, v in asked.stage_ms.items()}}
            if asked.stage_ms
            else {}
        ),
    }


def unknown_shapes(seed: int = 0) -> dict[str, trimesh.Trimesh]:
    """Objects in no LM-O frame: the service's demo shapes and `GENERATED` generated shapes."""
    rng = np.random.default_rng(seed)
    return {**demo_shapes(), **{f"shape_{i}": random_shape(rng) for i in range(GENERATED)}}


def false_alarms(cfg: DetectConfig, folder: Path, embedder: Embedder, frames: Sequence[Frame]) -> dict:
    """Detections per frame with only `unknown_shapes` registered (every one is false)."""
    shapes = unknown_shapes(cfg.seed)
    settings = service_settings(cfg.model, folder)
    state = load_state(settings, {embedder.modality: embedder})
    try:
        with bar(len(shapes), "register unknown shapes", "object") as b:
            ids: dict[int, int] = {}
            for name, mesh in shapes.items():
                reg = state.register_mesh(mesh, name, "none")
                ids[reg.record.object_id] = -1 - len(ids)  # no dataset object
                b.update()
        ours = ask_service(state, frames, ids, cfg)
        views = _views(state, embedder, dict.fromkeys(ids.values(), "none"))
    finally:
        close_state(state)
    out = {"objects": list(shapes), "frames": len(frames), "posedesc": _per_frame(ours.floor, len(frames))}
    if cfg.linemod:
        meshes = dict(zip(ids.values(), shapes.values(), strict=True))
        lm = linemod_detector(meshes, views, embedder)
        out["linemod"] = _per_frame(ask_linemod(lm, frames, cfg).floor, len(frames))
    return out


def _per_frame(hits: Sequence[Hit], n_frames: int) -> dict:
    per = Counter(h.frame for h in hits)
    return {
        "detections_per_frame": round(len(hits) / max(n_frames, 1), 3),
        "frames_with_any": len(per),
        "most_in_a_frame": max(per.values(), default=0),
    }


#: the table's columns: (heading, key of a figures block, as a percentage)
COLUMNS = (
    ("recall", "recall", True),
    ("precision", "precision", True),
    ("AP50", "ap50", True),
    ("<20deg", "rotation_within_20", True),
    ("dist err", "median_relative_distance_error", True),
    ("targets", "targets", False),
    ("hits", "hits", False),
)


def table(summary: dict) -> str:
    """The JSON's figures as text: each detector over all objects and per object, frame times, false alarms."""
    methods = [m for m in ("posedesc", "linemod") if m in summary]
    head = f"{'':>18}" + "".join(f"{h:>10}" for h, _, _ in COLUMNS)
    lines = [head]

    def row(name: str, block: dict) -> str:
        cells = []
        for _, key, pct in COLUMNS:
            v = block.get(key)
            cells.append(f"{'-':>10}" if v is None else f"{100 * v:>9.1f}%" if pct else f"{v:>10}")
        return f"{name:>18}" + "".join(cells)

    for m in methods:
        lines.append(row(f"{m} all", summary[m]["all"]))
        for o, block in summary[m]["per_object"].items():
            lines.append(row(f"{m} obj {o}", block))
    for m in methods:
        ms = summary[m]["frame_ms"]
        lines.append(f"{m}: frame time median {ms['median']} ms (p90 {ms['p90']})")
    if fa := summary.get("false_alarms"):
        for m in methods:
            if m in fa:
                lines.append(
                    f"{m}: {fa[m]['detections_per_frame']} false detections a frame with only "
                    f"{', '.join(fa['objects'])} registered ({fa['frames']} frames)"
                )
    return "\n".join(lines)
