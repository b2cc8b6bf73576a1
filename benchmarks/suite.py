"""`posedesc bench`: every section in one run, side by side with its baseline, into one JSON.

Sections: "descriptor" (throughput vs HOG), "recognition" (vs LineMOD at 8 / 100 / 1,000 objects),
"knn" (store size 10^4 ... 10^7, exact vs IVF), "http" (`POST /recognize` with concurrent clients),
"register" (`POST /objects`, 20k faces), "roll" (the roll-estimating set-up: from a decoded patch to the
answer over in-plane templates with query turns, beside upright templates and LineMOD; a 640x480 frame
over HTTP; registration with in-plane templates; `benchmarks/roll.py`), "train" (the network's training
throughput), "guards" (how long the refusals of hostile uploads, oversized and damaged meshes and a busy
port take; `benchmarks/serving/guards.py`), "milvus" (the template store through Milvus beside the embedded one,
at 100 objects and 10^6 templates, HNSW's recall, and how soon a replica sees another's registration and
deletion; `benchmarks/stores/milvus.py`), "detect" (every registered object found in a whole 640x480 LM-O frame,
in-process, at 8 objects and, opt-in, 100; the RGB-D Kinect frame at 8; `benchmarks/detection.py`), "fit" (on
request: the pose fit's time per answer and the call with and without it, on LM-O's validation frames in
colour, with rendered depth and on the Kinect frame; each object's fit models' seconds and bytes;
`benchmarks/fit.py`). The headline figures are copied to the top of the JSON (`summary`, and
the issue's keys `recognize_vs_linemod_speedup_100` and `register_20k_faces_s`) with the issue's targets.

The default run fits ten minutes on a 2-core machine; `everything()` (`posedesc bench --all`) adds what
does not (OPT_IN)."""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from tqdm import tqdm

from benchmarks import descriptor, detection, fit, recognition, roll, train_step
from benchmarks.descriptor import DescriptorConfig
from benchmarks.detection import DetectConfig
from benchmarks.fit import FitConfig
from benchmarks.recognition import RecognitionConfig
from benchmarks.roll import MODEL_KINDS, RollConfig
from benchmarks.serving import guards, over_http, registration
from benchmarks.serving.guards import GuardsConfig
from benchmarks.serving.over_http import HttpConfig
from benchmarks.stores import knn, memory, milvus
from benchmarks.stores.knn import KnnConfig
from benchmarks.stores.memory import MemoryConfig
from benchmarks.stores.milvus import MilvusConfig
from benchmarks.summary import summarise, targets_met
from benchmarks.timing import machine, pin_threads
from benchmarks.train_step import TrainStepConfig

SECTIONS = (
    "descriptor",
    "recognition",
    "knn",
    "http",
    "register",
    "roll",
    "train",
    "guards",
    "detect",
    "milvus",
    "memory",
    "fit",
)


#: sections run only when asked for (--only, --all): milvus starts a server and bulk-loads 10^6 templates;
#: memory fills stores of 1,000 objects; fit registers LM-O's 7 objects with two models and makes their
#: fit models, then 2 x (115 + 115 + 30) calls: 74 s with the first colour models (load 5-6), 35 s since
#: (load 1.5, docs/results/bench-fit.json), and the pose fit's own figures, not the default run's
ON_REQUEST = ("milvus", "memory", "fit")


DEFAULT_SECTIONS = tuple(s for s in SECTIONS if s not in ON_REQUEST)


#: What the default run leaves out, each past the ten minutes a default run may take on a 2-core machine
#: (seconds from docs/results/bench.json, bench-roll-*.json and bench-milvus.json, load average 0.3-6):
OPT_IN = {
    # LineMOD's build at 1,000 objects alone took 171 s, and the section 319 s in all (8, 100, 1,000)
    "recognition at 1,000 objects": "--objects 8,100,1000",
    # a second model doubles the roll section: 453 s for both against 144-217 s for the shipped one alone
    "the roll section's untrained stand-in model": "--roll-models shipped,untrained",
    "the milvus section (a Milvus server, 10^6 templates bulk-loaded: 328 s)": "--only milvus",
    # a store of 1,000 objects is ~9 GB of SQLite to write and read back
    "the memory section (resident memory at 100 and 1,000 objects)": "--only memory",
    # 92 registrations beyond the 8 objects, ~2.8 s each (2 cores, load 4.5), before a frame is asked
    "detection at 100 objects": "--detect-objects 8,100",
    # 35 s at load 1.5, most of it registering LM-O with two models
    "the fit section (the pose fit on and off; LM-O registered, its validation frames asked)": "--only fit",
}


DEFAULT_COUNTS = (8, 100)  # the recognition section's object counts by default


@dataclass
class BenchConfig:
    models: Path = Path("models")
    modality: str = "rgb"
    sections: tuple[str, ...] = DEFAULT_SECTIONS
    quick: bool = False
    seed: int = 0
    distinct: int | None = None  # shapes rendered (x48 image variants, benchmarks/objects.py); None: enough
    # for the largest object count, and at least 8 (the smallest store then holds 8 different shapes)
    level: int = 3  # template viewpoints (3: the paper's 301), here and in the benchmark's service
    setup_threads: int = 2  # onnxruntime threads for making template descriptors (not timed)
    register_repeats: int = 3
    descriptor: DescriptorConfig = field(default_factory=DescriptorConfig)
    recognition: RecognitionConfig = field(default_factory=lambda: RecognitionConfig(counts=DEFAULT_COUNTS))
    knn: KnnConfig = field(default_factory=KnnConfig)
    http: HttpConfig = field(default_factory=HttpConfig)
    train: TrainStepConfig = field(default_factory=TrainStepConfig)
    roll: RollConfig = field(default_factory=lambda: RollConfig(models=MODEL_KINDS[:1]))  # the shipped model
    guards: GuardsConfig = field(default_factory=GuardsConfig)
    milvus: MilvusConfig = field(default_factory=MilvusConfig)
    detect: DetectConfig = field(default_factory=DetectConfig)
    memory: MemoryConfig = field(default_factory=MemoryConfig)
    fit: FitConfig = field(default_factory=FitConfig)

    def everything(self) -> BenchConfig:
        """Every section at full size: the default run and OPT_IN."""
        return replace(
            self,
            sections=SECTIONS,
            recognition=replace(self.recognition, counts=RecognitionConfig().counts),
            roll=replace(self.roll, models=MODEL_KINDS),
            detect=replace(self.detect, counts=(8, 100)),
        )

    def shapes_needed(self) -> int:
        if self.distinct is not None:
            return self.distinct
        from benchmarks.objects import VARIANTS

        most = max(self.recognition.counts) if "recognition" in self.sections else 0
        most = max(most, self.http.objects if "http" in self.sections else 0)
        return max(8, -(-most // VARIANTS))

    def tiny(self) -> BenchConfig:
        """Everything at sizes a test can afford (level-1 templates: 21 per object)."""
        return replace(
            self,
            quick=True,
            distinct=3,
            level=1,
            register_repeats=1,
            descriptor=DescriptorConfig(patches=32, patches_b1=16, repeats=2),
            recognition=RecognitionConfig(
                counts=(8, 100), linemod_max_objects=100, queries=20, linemod_repeats=2
            ),
            knn=KnnConfig(
                sizes=(10**4, 2 * 10**4), queries=20, recall_queries=100, train_sample=39 * knn.NLIST
            ),
            http=HttpConfig(objects=8, concurrency=(1, 2), requests=10, rounds=1, warmup=4),
            train=TrainStepConfig(steps=2, warmup=1, samples_per_batch=8),
            # both models: the quick run covers what --all measures
            roll=replace(
                self.roll,
                models=MODEL_KINDS,
                objects=8,
                queries=20,
                warmup=2,
                http_requests=10,
                http_warmup=2,
            ),
            guards=GuardsConfig(repeats=1, fuzz_cases=20, small_only=True),
            milvus=replace(
                self.milvus, objects=3, large=(2000,), queries=20, recall_queries=20, registrations=1
            ),
            detect=replace(self.detect, counts=(2,), frames=1, warmup=0, rgbd_repeats=1),
            memory=MemoryConfig(counts=(2, 4), level=1),
            fit=replace(self.fit, max_frames=1, objects=2, warmup=0, kinect_repeats=1),
        )


#: the service's settings that change what a recognition does and costs and that no section sets itself
#: (the sections set the level, index kind, query turns and in-plane templates they measure)
RECOGNITION_SETTINGS = ("rerank", "roll_sweep", "relief_weight", "reject_above", "threads")


def recognition_settings() -> dict:
    """Those settings as every section's service runs with them (the defaults, or POSEDESC_* overrides),
    and the stages' constants that change the same (`service.pipeline.refine`, `service.pipeline.score`)."""
    from service.pipeline import refine, score
    from service.settings import Settings

    settings = Settings(demo_objects=False)
    out = {name: _jsonable(getattr(settings, name)) for name in RECOGNITION_SETTINGS}
    out |= {
        "roll_refine": refine.ROLL_REFINE,
        "refine_rounds": refine.REFINE_ROUNDS,
        "mask_coverage": score.MASK_COVERAGE,
    }
    return out


def run(cfg: BenchConfig) -> dict:
    from index.features.embed import MODEL_FILES, Embedder, fingerprint, load_models

    t_start = time.perf_counter()
    distinct = cfg.shapes_needed()
    cfg = replace(cfg, distinct=distinct)
    threads = pin_threads(ort_threads=1, faiss_threads=cfg.knn.search_threads, cv2_threads=1)
    out: dict = {"machine": machine(), "threads": threads, "config": _jsonable(asdict(cfg)), "sections": {}}
    out["service_settings"] = recognition_settings()
    out["threads"] |= {"setup_onnxruntime": cfg.setup_threads, "faiss_build": cfg.knn.build_threads}
    notes: list[str] = []
    seconds: dict[str, float] = {}
    path = cfg.models / MODEL_FILES[cfg.modality]
    if not path.is_file():
        raise FileNotFoundError(f"no {cfg.modality} model: {path} is missing")
    embedder = Embedder(path, threads=1)  # timed: one intra-op thread, as the service
    setup = load_models(cfg.models, threads=cfg.setup_threads)
    out["models"] = {
        m: {"file": str(e.path), "fingerprint": fingerprint(e.path), "descriptor_dim": e.dim}
        for m, e in setup.items()
    }
    objects = None
    if {"descriptor", "recognition", "http", "roll"} & set(cfg.sections):
        from benchmarks.objects import VARIANTS, render_objects
        from index.templates.register import TemplateConfig, template_views

        t0 = time.perf_counter()
        n_views = len(template_views("none", TemplateConfig(level=cfg.level)))
        with tqdm(total=distinct * n_views, desc="render shapes", unit="view", disable=None) as bar:
            objects = render_objects(
                distinct, embedder.info.size, embedder.info.window_mm, cfg.level, cfg.seed, bar.update
            )
        seconds["render_shapes"] = time.perf_counter() - t0
        notes.append(
            f"{cfg.distinct} procedural shapes rendered at {objects.templates_per_object} template views; "
            f"object j is shape j % {cfg.distinct} through one of {VARIANTS} exact image transforms "
            "(quarter turns, mirror, colour-channel order): see benchmarks/objects.py"
        )
    for name in cfg.sections:
        t0 = time.perf_counter()
        if name == "descriptor":
            assert objects is not None  # rendered above for this section
            out["sections"][name] = descriptor.run(objects, embedder, cfg.descriptor)
        elif name == "recognition":
            assert objects is not None
            rc = cfg.recognition
            out["sections"][name] = recognition.run(objects, embedder, setup[cfg.modality], rc)
        elif name == "knn":
            out["sections"][name] = knn.run(cfg.knn)
        elif name == "roll":
            assert objects is not None
            out["sections"][name] = roll.run(
                cfg.roll,
                objects,
                cfg.models,
                cfg.modality,
                cfg.level,
                cfg.seed,
                cfg.setup_threads,
                cfg.register_repeats,
            )
            notes += out["sections"][name]["notes"]
        elif name == "train":
            out["sections"][name] = train_step.run(cfg.modality, cfg.train, cfg.seed)
        elif name == "guards":
            out["sections"][name] = guards.run(cfg.guards, cfg.models)
        elif name == "milvus":
            out["sections"][name] = milvus.run(cfg.milvus)
        elif name == "memory":
            out["sections"][name] = memory.run(cfg.memory, cfg.models, cfg.seed)
        elif name == "detect":
            out["sections"][name] = detection.run(cfg.detect, cfg.models, cfg.level, cfg.seed)
            notes += out["sections"][name]["notes"]
        elif name == "fit":
            out["sections"][name] = fit.run(replace(cfg.fit, seed=cfg.seed), cfg.models, cfg.level)
            notes += out["sections"][name]["notes"]
        elif name in ("http", "register"):
            if "service" in seconds:  # both ran on the one service
                continue
            name = "service"
            out["sections"] |= _service(cfg, objects, setup)
        seconds[name] = time.perf_counter() - t0
    seconds["total"] = time.perf_counter() - t_start
    out["seconds"] = seconds
    out["machine"]["load_average_at_end"] = [round(x, 2) for x in os.getloadavg()]
    load = max(out["machine"]["load_average_at_start"][0], out["machine"]["load_average_at_end"][0])
    if load > 0.5 * (out["machine"]["cores_usable"] or 1):
        notes.append(
            f"other work was running (load average up to {load:.1f}): absolute figures are pessimistic"
        )
    out["capped"] = [c for s in out["sections"].values() if isinstance(s, dict) for c in s.get("capped", [])]
    out["notes"] = notes
    summary = summarise(out["sections"])
    out["summary"] = summary
    out["targets"] = targets_met(summary)
    # the required keys, at the top
    return {
        "recognize_vs_linemod_speedup_100": summary.get("recognize_vs_linemod_speedup_100"),
        "register_20k_faces_s": summary.get("register_20k_faces_s"),
        **out,
    }


def _service(cfg: BenchConfig, objects, setup) -> dict:
    """The HTTP and registration sections against one real service on a data dir of `cfg.http.objects`."""
    from benchmarks.serving.server import Server
    from benchmarks.stores.build import fill_data_dir

    out: dict = {}
    n = min(cfg.http.objects, objects.capacity) if objects is not None else 0
    env = {
        "POSEDESC_DEMO_OBJECTS": "false",
        "POSEDESC_SYNC_SECONDS": "600",  # registrations answer 201 with their timings
        "POSEDESC_THREADS": "1",
        "POSEDESC_LEVEL": str(cfg.level),
        "POSEDESC_INDEX_KIND": "flat",
        "POSEDESC_API_KEY": "",
    }
    with tempfile.TemporaryDirectory(prefix="posedesc-bench-") as tmp:
        data_dir = Path(tmp) / "data"
        if n:
            steps = n * (len(setup) + 1)
            with tqdm(total=steps, desc=f"service store: {n} objects", unit="step", disable=None) as bar:
                fill_data_dir(data_dir, setup, objects, n, bar.update)
        server = Server(data_dir, cfg.models, env)
        with server as url:
            if "http" in cfg.sections and objects is not None:
                out["http"] = over_http.run(url, objects, cfg.modality, replace(cfg.http, objects=n))
            if "register" in cfg.sections:
                out["register"] = registration.run(url, cfg.register_repeats, server.pid) | {
                    "store_objects_before": n
                }
    return out


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, Path):
        return str(x)
    return x
