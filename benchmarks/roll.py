"""The roll-estimating set-up against the issue's "still fast" targets, each beside its baseline in the
same run (`posedesc bench`, section "roll"):

1. In-process, from a decoded patch to the answer at `objects` objects:
   `service.recognition.recognise_decoded`, the call `POST /recognize` makes after decoding (the patch
   and its query turns, their descriptors in one batch, the k-NN over every in-plane variant, the
   collapse to k distinct answers), on a service state loaded as `posedesc serve` loads it
   (`service.state.load_state`) from a data dir filled through `Store.add_object`. For every model:
   templates over the whole turn (query turns 1, 2, 3) and, the baselines, upright templates
   (inplane_step 0, the existing set-up) and the same templates searched exactly ("exact": a flat
   index, 1 query turn; the timed set-ups use the service's default index, `index_kind`). LineMOD's
   figure is the "recognition" section's (upright templates, same run): `suite.py` puts the ratio
   beside.
2. Over HTTP, one client: a 640x480 PNG frame (and the 64 px patch) to the real service (`posedesc
   serve` on loopback) serving that data dir with the first model that has its own `inplane_step`,
   query turns `http_query_turns`. Baseline: the "http" section's frame (the shipped models, upright).
3. `POST /objects` of the 20k-face mesh to that service: the default models (the other modalities of the
   models folder, with their own templates) and that model with its in-plane templates. Baseline: the
   "register" section.

Models (`models`): "shipped" is the models folder's model of the modality; "untrained" a stand-in
exported into a temporary folder (`training.model.DescriptorNet`, arch "trunk" for rgb, the paper's for
depth and rgbd, 32-d, metadata `inplane_step`): timing does not depend on trained weights; anything
else is a path to an .onnx. The JSON names each by its fingerprint. A model without `inplane_step` in
its metadata (trained upright) gets its in-plane templates from the settings (POSEDESC_INPLANE_STEP =
`inplane_step`, POSEDESC_INPLANE_MAX = 180), as the service would with them; it is not served in 2-3.

The objects: `benchmarks.objects.inplane_template_sets` (procedural shapes through exact image
transforms, rendered and turned as registration does); the query: the "recognition" section's patch.
Threads: onnxruntime one intra-op thread for timed calls (the service's), `setup_threads` for making
templates; FAISS and OpenCV one (`pin_threads`, and the service's `THREADS=1`); torch only exports the
stand-in, untimed."""

from __future__ import annotations

import contextlib
import io
import shutil
import statistics
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from benchmarks.objects import TURN_FREE_VARIANTS, ObjectSet, inplane_template_sets
from benchmarks.serving import over_http, registration
from benchmarks.serving.server import Server
from benchmarks.stores.build import fill_store
from benchmarks.timing import measure
from index.features.embed import MODEL_FILES, Embedder, fingerprint, load_models, store_key, store_keys
from index.store import TemplateSet
from index.templates.register import TemplateConfig

MODEL_KINDS = ("shipped", "untrained")
#: concurrent clients of the frame's throughput over HTTP (issue 28: 4 clients, beside one)
FRAME_CLIENTS = 4


@dataclass(frozen=True)
class RollConfig:
    models: tuple[str, ...] = MODEL_KINDS  # "shipped", "untrained" or paths to .onnx models
    objects: int = 100
    inplane_step: float = 30.0  # the stand-in's metadata, and the settings for a model without its own
    query_turns: tuple[int, ...] = (1, 2, 3)
    queries: int = 200  # timed recognitions per set-up
    warmup: int = 5
    k: int = 5
    http_requests: int = 100  # frame requests over HTTP, one client
    http_warmup: int = 5
    http_query_turns: int = 1  # POSEDESC_QUERY_TURNS of the served set-up
    #: POSEDESC_INDEX_KIND of the timed set-ups (the service's default); the in-process baseline "exact"
    #: times the primary model's in-plane templates with an exact ("flat") index beside it
    index_kind: str = "auto"
    #: write a profile of one query (the primary model's in-plane templates, the first query-turn count)
    #: here: cProfile, the top functions by self time and a flame graph (`benchmarks.profile`)
    profile: Path | None = None
    profile_calls: int = 20


@dataclass
class Model:
    label: str
    path: Path
    timed: Embedder  # one intra-op thread, as the service
    setup: Embedder  # makes the templates
    settings: dict[str, float | None]  # the in-plane settings of its roll set-up (None: its own)
    angles: np.ndarray  # its templates' in-plane angles in that set-up

    @property
    def own_step(self) -> float:
        return self.timed.info.inplane_step


def run(
    cfg: RollConfig,
    objects: ObjectSet,
    models_dir: Path,
    modality: str,
    level: int = 3,
    seed: int = 0,
    setup_threads: int = 2,
    register_repeats: int = 3,
) -> dict:
    with tempfile.TemporaryDirectory(prefix="posedesc-bench-roll-") as tmp_name:
        tmp = Path(tmp_name)
        models = _models(cfg, models_dir, modality, level, tmp, setup_threads, objects.window_mm, seed)
        served = next((m for m in models if m.own_step > 0), None)
        # the default models of the other modalities, with their own templates, for the served set-up
        others = {
            m: e
            for m, e in load_models(models_dir, threads=setup_threads).items()
            if m != modality and served is not None
        }
        out: dict = {
            "modality": modality,
            "objects": cfg.objects,
            "k": cfg.k,
            "level": level,
            "query": f"the recognition section's patch (64 px PNG, decoded once), k = {cfg.k}; "
            "`recognise_decoded` timed from the decoded patch to the answer",
            "threads": {
                "onnxruntime_intra_op": 1,
                "onnxruntime_setup": setup_threads,
                "faiss_omp": 1,
                "opencv": 1,
                "torch": "the stand-in's export only (untimed)",
            },
            "models": {m.label: _describe(m, level) for m in models},
            # the model of the figures: the served one, else the first
            "primary": (served or models[0]).label,
            "in_process": {},
            "server": None,
            "notes": [],
            "capped": [],
        }
        todo = {m.label: (m.setup, m.angles) for m in models}
        todo |= {
            f"default {m}": (e, TemplateConfig(level).inplane(e.info.inplane_step)) for m, e in others.items()
        }
        t0 = time.perf_counter()
        total = cfg.objects * len(todo)
        with tqdm(total=total, desc="roll: embed templates", unit="object", disable=None) as bar:
            sets = inplane_template_sets(
                cfg.objects, todo, level, objects.rgb.shape[2], objects.window_mm, seed, bar.update
            )
        out["embed_templates_s"] = time.perf_counter() - t0
        out["template_objects"] = (
            f"shapes 0..{-(-cfg.objects // len(TURN_FREE_VARIANTS)) - 1} (benchmarks.objects.shapes, seed {seed}) "
            f"through {len(TURN_FREE_VARIANTS)} transforms without a quarter turn"
        )
        query = _query(objects, modality, cfg.k)
        primary = served or models[0]
        for i, m in enumerate(models):
            data, upright = tmp / f"roll-{i}", tmp / f"upright-{i}"
            stores = {modality: store_key(m.timed)}
            roll_sets: dict[str, list[TemplateSet]] = {modality: sets[m.label]}
            if m is served:
                stores |= store_keys(others)
                roll_sets |= {o: sets[f"default {o}"] for o in others}
            with tqdm(
                total=2 * cfg.objects, desc=f"roll: stores ({m.label})", unit="object", disable=None
            ) as b:
                fill_store(data, stores, roll_sets, b.update)
                fill_store(
                    upright, {modality: stores[modality]}, {modality: _upright(sets[m.label])}, b.update
                )
            out["in_process"][m.label] = {
                "upright": _in_process(
                    upright, m, {"inplane_step": 0.0, "inplane_max": None}, query, cfg, level
                ),
                "roll": _in_process(
                    data, m, m.settings, query, cfg, level, cfg.profile if m is primary else None
                ),
            }
            if m is served or (served is None and i == 0):  # the same templates, searched exactly
                exact = replace(cfg, index_kind="flat", query_turns=cfg.query_turns[:1])
                out["in_process"][m.label]["exact"] = _in_process(data, m, m.settings, query, exact, level)
            shutil.rmtree(upright)
            if m is served:  # the real service on the same data dir
                out["server"] = _served(cfg, m, others, data, tmp, objects, modality, level, register_repeats)
            shutil.rmtree(data)
        if served is None:
            out["notes"].append(
                "no model has its own inplane_step: the served set-up (HTTP frame, registration) is not measured"
            )
        for n, row in out["in_process"][primary.label]["roll"]["by_turns"].items():
            out[f"stages_ms_{cfg.objects}_q{n}"] = row["stages_median_ms"]
            out[f"stages_p90_ms_{cfg.objects}_q{n}"] = row["stages_p90_ms"]
        if (prof := out["in_process"][primary.label]["roll"].get("profile")) is not None:
            out["profile"] = prof
    return out


def _models(
    cfg: RollConfig,
    models_dir: Path,
    modality: str,
    level: int,
    tmp: Path,
    setup_threads: int,
    window_mm: float,
    seed: int,
) -> list[Model]:
    out: list[Model] = []
    seen: set[str] = set()
    for spec in cfg.models:
        if spec == "shipped":
            path = models_dir / MODEL_FILES[modality]
            if not path.is_file():
                raise FileNotFoundError(f"no {modality} model: {path} is missing")
        elif spec == "untrained":
            path = stand_in(
                modality, tmp / "untrained" / MODEL_FILES[modality], cfg.inplane_step, window_mm, seed
            )
        else:
            path = Path(spec)
            if not path.is_file():
                raise FileNotFoundError(f"roll model {spec}: no such file")
        if fingerprint(path) in seen:
            continue
        seen.add(fingerprint(path))
        timed = Embedder(path, threads=1)
        if timed.modality != modality:
            raise ValueError(f"{path} is a {timed.modality} model, not {modality}")
        own = timed.info.inplane_step
        settings: dict[str, float | None] = (
            {"inplane_step": None, "inplane_max": None}
            if own > 0
            else {"inplane_step": cfg.inplane_step, "inplane_max": 180.0}
        )
        tc = TemplateConfig(level, settings["inplane_step"], settings["inplane_max"])
        out.append(Model(spec, path, timed, Embedder(path, threads=setup_threads), settings, tc.inplane(own)))
    return out


def stand_in(modality: str, out: Path, inplane_step: float, window_mm: float, seed: int = 0) -> Path:
    """An untrained model of the coming design (rgb: the frozen MobileNetV2 trunk and its head; depth and
    rgbd: the paper's network), 32-d, its metadata saying `inplane_step`: a stand-in for timing."""
    import torch

    from training.export import export_onnx
    from training.model import DescriptorNet, NetConfig

    torch.manual_seed(seed)
    net = DescriptorNet(NetConfig(modality, 32, arch="trunk" if modality == "rgb" else "paper"))
    extra = {"inplane_step": str(float(inplane_step)), "note": "untrained stand-in for posedesc bench"}
    with contextlib.redirect_stdout(io.StringIO()):  # the exporter's progress lines
        return export_onnx(net, out, window_mm, extra)


def _describe(m: Model, level: int) -> dict:
    return {
        "file": str(m.path),
        "fingerprint": fingerprint(m.path),
        "descriptor_dim": m.timed.dim,
        "metadata_inplane_step": m.own_step,
        "stand_in": m.label == "untrained",
        "roll_settings": {f"POSEDESC_{k.upper()}": v for k, v in m.settings.items() if v is not None}
        or "none: the model's own inplane_step",
        "templates_per_viewpoint": len(m.angles),
        "templates_per_object": _viewpoints(level) * len(m.angles),
    }


def _viewpoints(level: int) -> int:
    from index.templates.viewpoints import hemisphere

    return len(hemisphere(level))


def _upright(sets: list[TemplateSet]) -> list[TemplateSet]:
    """The in-plane 0 templates: what an upright registration makes (the same renders, unturned)."""
    out = []
    for s in sets:
        keep = s.poses[:, 2] == 0
        out.append(TemplateSet(s.poses[keep], s.descriptors[keep]))
    return out


def _query(objects: ObjectSet, modality: str, k: int):
    from service.pipeline.query import Query

    req = over_http.patch_request(objects, modality)
    return Query(
        rgb=req.files["rgb"][1] if "rgb" in req.files else None,
        depth=req.files["depth"][1] if "depth" in req.files else None,
        k=k,
    )


def _in_process(
    data: Path,
    m: Model,
    inplane: dict[str, float | None],
    q,
    cfg: RollConfig,
    level: int,
    profile_dir: Path | None = None,
) -> dict:
    """`recognise_decoded` on the state `posedesc serve` would load from `data`, per query-turn count;
    with `profile_dir`, the first count's calls also profiled there."""
    from service.pipeline.query import decode
    from service.settings import Settings
    from service.state import close_state, load_state

    settings = Settings(
        data_dir=data,
        demo_objects=False,
        threads=1,
        level=level,
        index_kind=cfg.index_kind,
        query_turns=1,
        inplane_step=inplane["inplane_step"],
        inplane_max=inplane["inplane_max"],
    )
    state = load_state(settings, {m.timed.modality: m.timed})
    try:
        d = decode(state, q)
        mi = state.store.snapshot.models[m.timed.modality]
        out: dict = {
            "templates": mi.size,
            "index": type(getattr(mi, "index", None)).__name__,
            "templates_per_viewpoint": len(state.templates.inplane(m.own_step)),
            "settings": {k: v for k, v in inplane.items() if v is not None},
            "by_turns": {},
        }
        for n in cfg.query_turns:
            st = replace(state, settings=state.settings.model_copy(update={"query_turns": n}))
            out["by_turns"][str(n)] = _time_calls(st, q, d, cfg)
            if profile_dir is not None and n == cfg.query_turns[0]:
                out["profile"] = _profile(st, q, d, cfg, profile_dir, m, n)
    finally:
        close_state(state)
    return out


def _time_calls(state, q, d, cfg: RollConfig) -> dict:
    from service.pipeline.answer import Result
    from service.recognition import recognise_decoded

    results: list[Result] = []

    def call() -> None:
        results.append(recognise_decoded(state, q, d))

    t = measure(call, cfg.queries, warmup=cfg.warmup)
    timed = results[cfg.warmup :]
    # every key the pipeline timed (its stages, `decode` when timed, and the sums), in its order
    keys = list(dict.fromkeys(k for r in timed for k in r.timings_ms))
    per = {k: [r.timings_ms[k] for r in timed if k in r.timings_ms] for k in keys}
    best = timed[-1].matches[0] if timed[-1].matches else None
    return t.ms() | {
        "stages_median_ms": {k: statistics.median(v) for k, v in per.items()},
        "stages_p90_ms": {k: float(np.percentile(v, 90)) for k, v in per.items()},
        "top1_object": None if best is None else best.object_id - 1,  # object 0 is the query's shape
        "top1_inplane": None if best is None else best.inplane,
    }


def _profile(state, q, d, cfg: RollConfig, out_dir: Path, m: Model, turns: int) -> dict:
    from benchmarks.profile import profile
    from service.recognition import recognise_decoded

    title = (
        f"recognise_decoded, {m.label} {m.timed.modality} model ({fingerprint(m.path)[:8]}), "
        f"{cfg.objects} objects, in-plane templates, {turns} query turn(s), k = {cfg.k}"
    )
    return profile(lambda: recognise_decoded(state, q, d), cfg.profile_calls, out_dir, title, cfg.warmup)


def _served(
    cfg: RollConfig,
    m: Model,
    others: dict[str, Embedder],
    data: Path,
    tmp: Path,
    objects: ObjectSet,
    modality: str,
    level: int,
    register_repeats: int,
) -> dict:
    served_models = tmp / "served-models"
    served_models.mkdir()
    shutil.copyfile(m.path, served_models / MODEL_FILES[modality])
    for o, e in others.items():
        shutil.copyfile(e.path, served_models / MODEL_FILES[o])
    env: dict[str, str | None] = {
        "POSEDESC_DEMO_OBJECTS": "false",
        "POSEDESC_SYNC_SECONDS": "600",  # registrations answer 201 with their timings
        "POSEDESC_THREADS": "1",
        "POSEDESC_LEVEL": str(level),
        "POSEDESC_INDEX_KIND": cfg.index_kind,
        "POSEDESC_API_KEY": "",
        "POSEDESC_QUERY_TURNS": str(cfg.http_query_turns),
        "POSEDESC_INPLANE_STEP": None,  # each model's own
        "POSEDESC_INPLANE_MAX": None,
    }
    per_object = {modality: _viewpoints(level) * len(m.angles)}
    per_object |= {
        o: _viewpoints(level) * len(TemplateConfig(level).inplane(e.info.inplane_step))
        for o, e in others.items()
    }
    out: dict = {
        "model": m.label,
        "fingerprint": fingerprint(m.path),
        "models": {
            o: fingerprint(served_models / f) for o, f in MODEL_FILES.items() if (served_models / f).is_file()
        },
        "templates_per_object": per_object,
        "objects": cfg.objects,
        "query_turns": cfg.http_query_turns,
        "settings": {k: v for k, v in env.items() if v is not None},
    }
    frame = over_http.frame_request(modality)
    patch = over_http.patch_request(objects, modality)
    server = Server(data, served_models, env)
    with server as url:
        out["frame_640x480"] = _http(url, frame, cfg) | {
            "request": "README's demo frame: " + "+".join(frame.files) + " PNGs, camera fields, k = 5",
        }
        out[f"frame_640x480_{FRAME_CLIENTS}_clients"] = _http(url, frame, cfg, FRAME_CLIENTS) | {
            "request": f"the same frame from {FRAME_CLIENTS} clients at once",
        }
        out["patch"] = _http(url, patch, cfg) | {"request": "the query patch as PNG, k = 5"}
        out["register"] = registration.run(url, register_repeats, server.pid) | {
            "store_objects_before": cfg.objects
        }
    return out


def _http(url: str, req: over_http.Request, cfg: RollConfig, clients: int = 1) -> dict:
    over_http.load(url, req, clients, cfg.http_warmup)
    return over_http.load(url, req, clients, cfg.http_requests).summary()
