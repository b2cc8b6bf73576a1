"""The pose fit's cost (section "fit"): `service.recognition.recognise_decoded`, what `POST /recognize` runs
after decoding, timed with the fit on (`pose_fit` 1: the best answer fitted over six degrees of freedom,
`service.pipeline.fit`) and off (0), side by side on the same state, frames and queries.

The state is built as `posedesc serve` builds it (`service.state.load_state`, the service's settings with
`POSEDESC_*` overrides, the benchmark's models dir) in a temporary data dir; LM-O's objects are registered
by the service's registration (`evaluation.served.register_objects`, as `POST /objects` does), with the fit
off so that no model is made behind the timings (`AppState.warm`). Then each object's fit models are made
on this thread as the service makes them (`service.pipeline.fit.Shapes`: the drawing mesh read from the
store, `index.draw.DrawMesh`, then `ColourModel.of` and `DepthModel.of`), their seconds and bytes kept.

Queries are what a user sends about each annotated instance (`evaluation.queries.query`: the frame, its
camera, the true centre and, without depth, the true distance), each frame decoded once. For each frame
the pipelines swap (`state.settings`, as `evaluation.openset` swaps them): its instances without the fit,
then with it, the order alternating frame by frame so neither setting always comes second. Rows:

- colour: LM-O's validation frames (the rgb model's `split_frames` "val") through the rgb model;
- rendered depth: the same frames' colour with depth rendered from their ground truth
  (`evaluation.paper.samples.rendered_depth_frames`, the service protocol's way) through the RGB-D model;
- Kinect: the real Kinect frame (`lmo-depth`), `kinect_repeats` times, through the RGB-D model.

Each row: per setting, p50 / p90 of the call (`timings_ms["total"]`, the stages and the fit) and its wall
time, the median of every stage; with the fit on, p50 / p90 / max of `timings_ms["fit"]` (one answer a
call: the fit's time is the time per answer) and how many fits moved the pose; the ratio of the calls'
p50s. Threads: as the service's (`threads`, 1: onnxruntime, FAISS and OpenCV one thread a call), calls
one at a time on this thread."""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from collections.abc import Iterable, Iterator, Sequence
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from benchmarks.detection import LMO, LMO_DEPTH
from benchmarks.timing import ratio
from evaluation.paper.samples import REAL, REAL_COLOUR_RENDERED_DEPTH, select_instances
from evaluation.queries import frame_files, query
from evaluation.served import register_objects
from index.data.bop import BopDataset, Instance
from index.features.embed import Embedder, fingerprint, load_models
from service.errors import ApiError
from service.pipeline.answer import Result
from service.pipeline.query import Decoded, Query, decode
from service.recognition import recognise_decoded
from service.settings import Settings
from service.state import AppState, close_state, load_state

#: the issue's targets of the fit's p50 per answer (ms), 2 cores
TARGET_COLOUR_MS, TARGET_DEPTH_MS = 30.0, 15.0
SETTINGS = ("off", "on")  # the rows' settings: `pose_fit` 0 and 1


@dataclass(frozen=True)
class FitConfig:
    # the LM-O scene 2 frames sent; None: the rgb model's validation frames (`split_frames` "val": 20,
    # 115 instances at min_visib 0.5), the frames the fit's accuracy was measured on (docs/results/fit-*)
    frames: tuple[int, ...] | None = None
    max_frames: int | None = None  # at most this many of them (the first)
    objects: int | None = None  # the first n LM-O objects registered and asked about; None: all 7
    min_visib: float = 0.5  # the evaluation's (evaluation.config.Config): the Kinect frame keeps 6 of 7
    warmup: int = 1  # untimed calls (each setting) on the first instance before the timed ones
    # rendered depth for the colour frames: 3.2 s to render the 20 val frames, and a second pair of calls a query
    rendered: bool = True
    kinect_repeats: int = 5  # the Kinect frame's 6 instances, each this many times a setting
    lmo: Path = LMO
    lmo_depth: Path = LMO_DEPTH
    scene: int = 2
    seed: int = 0


@dataclass
class _Calls:
    """One setting's calls in a row: each call's `timings_ms`, wall seconds, whether the fit moved the best
    answer's pose (None: not fitted) and whether that answer was the instance's object."""

    timings: list[dict[str, float]]
    wall_s: list[float]
    moved: list[bool | None]
    right: list[bool]
    refused: int = 0


def run(cfg: FitConfig, models_dir: Path, level: int = 3) -> dict:
    """The section's JSON; without LM-O at `cfg.lmo`, no rows and a note saying so."""
    if not (cfg.lmo / "models" / "models_info.json").is_file():
        note = f"no LM-O at {cfg.lmo}: the fit section needs its meshes and frames; nothing measured"
        return {"rows": {}, "models_made": {}, "notes": [note], "capped": []}
    dataset = BopDataset(cfg.lmo)
    obj_ids = dataset.obj_ids[: cfg.objects]
    base = Settings(demo_objects=False)
    embedders = {m: e for m, e in load_models(models_dir, base.threads).items() if m in ("rgb", "rgbd")}
    if "rgb" not in embedders:
        raise FileNotFoundError(f"no rgb model in {models_dir}: the fit section needs posedesc-rgb.onnx")
    frames = _frames(cfg, embedders["rgb"])
    instances = select_instances(dataset, cfg.scene, cfg.min_visib, frames, obj_ids)
    if not instances:
        raise ValueError(f"{cfg.lmo}: no instance of objects {obj_ids} in scene {cfg.scene} frames {frames}")
    out: dict = {
        "models": {
            m: {"file": str(e.path), "fingerprint": fingerprint(e.path)} for m, e in embedders.items()
        },
        "frames": {
            "dataset": str(cfg.lmo),
            "scene": cfg.scene,
            "frames": frames,
            "instances": len(instances),
        },
        "objects": [f"obj_{o:06d}" for o in obj_ids],
        "per_answer": "pose_fit 1: one answer fitted a call, so the fit's time a call is its time an answer",
        "rows": {},
        "notes": [],
        "capped": [],
    }
    if "rgbd" not in embedders:
        out["notes"].append(f"no rgbd model in {models_dir}: the depth rows are not measured")
    with tempfile.TemporaryDirectory(prefix="posedesc-bench-fit-") as tmp:
        common = {"data_dir": Path(tmp) / "data", "models_dir": models_dir, "level": level}
        off = base.model_copy(update={**common, "pose_fit": 0})
        on = off.model_copy(update={"pose_fit": 1})
        out["settings"] = {"level": level, "threads": on.threads, "pose_fit": {"off": 0, "on": 1}}
        out["threads"] = {
            "onnxruntime_intra_op": on.threads,
            "faiss_omp": on.threads,
            "opencv": on.threads,
            "numpy_blas": os.environ.get("OMP_NUM_THREADS", "unset (the library's default)"),
            "calls": "one at a time on one thread, as one of the service's recognition threads runs it",
        }
        state = load_state(off, embedders)  # registered with the fit off: no model made behind the timings
        try:
            t0 = time.perf_counter()
            meshes, dataset_ids = register_objects(state, dataset, obj_ids)
            out["register_s"] = time.perf_counter() - t0
            out["models_made"] = models_made(state, dataset_ids)
            pair = {"off": off, "on": on}
            sent = frame_files(dataset, instances, "rgb", REAL, cfg.seed)
            out["rows"]["colour"] = _row(state, pair, sent, dataset_ids, cfg.warmup, "fit: colour")
            if "rgbd" in embedders and cfg.rendered:
                out["rows"]["rendered_depth"] = _rendered(
                    state, pair, dataset, instances, meshes, dataset_ids, cfg
                )
            if "rgbd" in embedders:
                kinect = _kinect(cfg, obj_ids)
                if kinect is None:
                    out["notes"].append(f"no Kinect frame at {cfg.lmo_depth}: its row is not measured")
                else:
                    ds, found = kinect
                    repeated = list(frame_files(ds, found, "rgbd", REAL, cfg.seed)) * cfg.kinect_repeats
                    row = _row(state, pair, repeated, dataset_ids, cfg.warmup, "fit: Kinect RGB-D")
                    out["rows"]["kinect_depth"] = row | {
                        "data": f"{cfg.lmo_depth} scene {cfg.scene}: the real Kinect frame, "
                        f"{len(found)} instances x {cfg.kinect_repeats}"
                    }
        finally:
            close_state(state)
    out["rows"]["colour"]["data"] = "real LM-O colour frames, true centre and distance sent"
    if "rendered_depth" in out["rows"]:
        out["rows"]["rendered_depth"]["data"] = (
            "rendered: the same frames' real colour with depth rendered from their ground truth (every "
            "annotated object, the table, the sensor model: evaluation.paper.samples.rendered_depth_frames)"
        )
    return out


def _frames(cfg: FitConfig, embedder: Embedder) -> list[int]:
    from evaluation.splits import split_frames

    frames = list(cfg.frames) if cfg.frames else split_frames(embedder.info.extra, cfg.lmo, cfg.scene, "val")
    if not frames:
        raise ValueError(
            f"{embedder.path} names no val frames of {cfg.lmo.name} scene {cfg.scene} (no split_frames in "
            "its metadata): give the fit section its frames"
        )
    return frames[: cfg.max_frames]


def models_made(state: AppState, dataset_ids: dict[int, int]) -> dict:
    """Each registered object's fit models made as the service makes them (`Shapes`), timed: the drawing
    mesh from the stored GLB, then the colour model and the depth model from it; seconds and bytes. The
    models stay in the state's caches, so the timed calls do not make them."""
    per: dict[str, dict] = {}
    for oid, o in tqdm(dataset_ids.items(), desc="fit: models", unit="object", disable=None):
        t0 = time.perf_counter()
        draw = state.draw_meshes.get(oid)
        t1 = time.perf_counter()
        colour = state.shapes.colour.get(oid)
        t2 = time.perf_counter()
        depth = state.shapes.depth.get(oid)
        t3 = time.perf_counter()
        assert draw is not None and colour is not None and depth is not None  # registered with a mesh
        per[f"obj_{o:06d}"] = {
            "draw_faces": len(draw.faces),
            "draw_mesh_s": t1 - t0,
            "colour_s": t2 - t1,
            "colour_bytes": colour.nbytes,
            "depth_s": t3 - t2,
            "depth_bytes": depth.nbytes,
        }
    med = {k: statistics.median(r[k] for r in per.values()) for k in ("colour_s", "depth_s")}
    return {
        "by_object": per,
        "colour_s_median": med["colour_s"],
        "colour_s_max": max(r["colour_s"] for r in per.values()),
        "depth_s_median": med["depth_s"],
        "depth_s_max": max(r["depth_s"] for r in per.values()),
        "colour_bytes_max": max(r["colour_bytes"] for r in per.values()),
        "depth_bytes_max": max(r["depth_bytes"] for r in per.values()),
    }


def _kinect(cfg: FitConfig, obj_ids: Sequence[int]) -> tuple[BopDataset, list[Instance]] | None:
    """The Kinect frame's dataset and its instances of the registered objects; None where it is absent."""
    if not (cfg.lmo_depth / "test" / f"{cfg.scene:06d}" / "depth").is_dir():
        return None
    ds = BopDataset(cfg.lmo_depth)
    found = select_instances(ds, cfg.scene, cfg.min_visib, None, obj_ids)
    return (ds, found) if found else None


def _rendered(state, pair, dataset, instances, meshes, dataset_ids, cfg: FitConfig) -> dict:
    """The depth row of the colour frames, their depth rendered on this thread (not timed in the calls)."""
    from index.templates.render import Renderer

    cache = dict(meshes)  # the frames' other annotated objects join it
    with closing(Renderer()) as renderer:
        t0 = time.perf_counter()
        sent = list(
            frame_files(
                dataset, instances, "rgbd", REAL_COLOUR_RENDERED_DEPTH, cfg.seed, renderer, cache,
                state.settings.max_faces,
            )
        )  # fmt: skip
        render_s = time.perf_counter() - t0
    row = _row(state, pair, sent, dataset_ids, cfg.warmup, "fit: rendered depth")
    return row | {"render_s": render_s}


def _row(
    state: AppState,
    pair: dict[str, Settings],
    sent: Iterable[tuple[list[Instance], bytes | None, bytes | None, float]],
    dataset_ids: dict[int, int],
    warmup: int,
    desc: str,
) -> dict:
    """Every instance of every frame asked with each setting of `pair` (see the module's docstring)."""
    frames = list(sent)
    calls = {name: _Calls([], [], [], []) for name in pair}
    n = sum(len(g) for g, *_ in frames)
    with tqdm(total=n * len(pair), desc=desc, unit="call", disable=None) as bar:
        for i, (group, rgb, depth, scale) in enumerate(frames):
            d = decode(state, Query(rgb=rgb, depth=depth, depth_scale=scale))
            queries = [(inst, query(inst, rgb, depth, scale)) for inst in group]
            order = SETTINGS if i % 2 == 0 else SETTINGS[::-1]
            for name in order:
                state.settings = pair[name]
                state.pipelines  # noqa: B018  # built here, not in the first timed call
                if i == 0:
                    for _ in range(warmup):
                        _ask(state, queries[0][1], d)
                for inst, q in queries:
                    _record(calls[name], _ask(state, q, d), inst, dataset_ids)
                    bar.update()
    state.settings = pair["off"]
    sides = {name: _figures(c) for name, c in calls.items()}
    on, off = sides["on"], sides["off"]
    return {
        "frames": len(frames),
        "calls": n,
        "modality": d.modality,
        **sides,
        "call_p50_ratio_on_off": ratio(on["call_p50_ms"], off["call_p50_ms"]),
        "call_p50_added_ms": on["call_p50_ms"] - off["call_p50_ms"],
    }


def _ask(state: AppState, q: Query, d: Decoded) -> tuple[Result | None, float]:
    """One call and its wall seconds; None: refused (the service's 4xx)."""
    t0 = time.perf_counter()
    try:
        result = recognise_decoded(state, q, d)
    except ApiError:
        result = None
    return result, time.perf_counter() - t0


def _record(
    c: _Calls, asked: tuple[Result | None, float], inst: Instance, dataset_ids: dict[int, int]
) -> None:
    result, wall = asked
    if result is None:
        c.refused += 1
        return
    c.timings.append(result.timings_ms)
    c.wall_s.append(wall)
    fit = result.fits[0] if result.fits else None
    c.moved.append(None if fit is None else fit.moved)
    c.right.append(bool(result.matches) and dataset_ids.get(result.matches[0].object_id) == inst.obj_id)


def _figures(c: _Calls) -> dict:
    """One setting's figures (ms): the call's and, where it ran, the fit's percentiles; stage medians."""
    keys = list(dict.fromkeys(k for t in c.timings for k in t))
    per = {k: [t[k] for t in c.timings if k in t] for k in keys}
    fit = per.get("fit", [])
    return {
        "runs": len(c.timings),
        "refused": c.refused,
        "call_p50_ms": _pct(per.get("total", []), 50),
        "call_p90_ms": _pct(per.get("total", []), 90),
        "wall_p50_ms": _pct([s * 1e3 for s in c.wall_s], 50),
        "stages_median_ms": {k: statistics.median(v) for k, v in per.items()},
        "fit_runs": len(fit),
        "fit_p50_ms": _pct(fit, 50),
        "fit_p90_ms": _pct(fit, 90),
        "fit_max_ms": max(fit) if fit else None,
        "fit_moved": sum(m is True for m in c.moved),
        "right_object": sum(c.right),
    }


def _pct(values: Sequence[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if len(values) else None


def summary(fi: dict) -> dict:
    """`fit_<row>_p50_ms` / `_p90_ms` (the fit per answer), `fit_<row>_call_p50_ms_on` / `_off` and
    `fit_<row>_call_ratio`, for rows colour, rendered_depth and kinect_depth; the models' seconds and
    bytes; `fit_depth_p50_ms`: the Kinect frame's (real depth), else the rendered depth's."""
    out: dict = {}
    for name, row in fi["rows"].items():
        out[f"fit_{name}_p50_ms"] = row["on"]["fit_p50_ms"]
        out[f"fit_{name}_p90_ms"] = row["on"]["fit_p90_ms"]
        for side in SETTINGS:
            out[f"fit_{name}_call_p50_ms_{side}"] = row[side]["call_p50_ms"]
        out[f"fit_{name}_call_ratio"] = row["call_p50_ratio_on_off"]
    depth = fi["rows"].get("kinect_depth") or fi["rows"].get("rendered_depth")
    if depth is not None:
        out["fit_depth_p50_ms"] = depth["on"]["fit_p50_ms"]
    if mm := fi.get("models_made"):
        for k in ("colour_s_median", "colour_s_max", "depth_s_median", "depth_s_max", "colour_bytes_max",
                  "depth_bytes_max"):  # fmt: skip
            out[f"fit_model_{k}"] = mm[k]
    return out


def table(fi: dict) -> Iterator[list[str]]:
    """The rows of the section's table: row, calls, fit p50 / p90, call p50 off / on, ratio, moved."""
    for name, row in fi["rows"].items():
        on, off = row["on"], row["off"]
        yield [
            name,
            row["modality"],
            str(row["calls"]),
            *(f"{x:.1f}" if x is not None else "-" for x in (on["fit_p50_ms"], on["fit_p90_ms"])),
            *(f"{x:.1f}" if x is not None else "-" for x in (off["call_p50_ms"], on["call_p50_ms"])),
            f"{row['call_p50_ratio_on_off']:.2f}" if row["call_p50_ratio_on_off"] else "-",
            f"{on['fit_moved']}/{on['fit_runs']}",
        ]
