"""One recognition in-process, ours against LineMOD, at growing numbers of objects.

Ours: the query patch -> network input -> descriptor (onnxruntime, batch 1) -> the k nearest templates
(`Snapshot.search`, exact FAISS), the calls `service/recognition.py` makes after decoding. LineMOD: the
same patch matched by `cv2.linemod` against the same templates, in the evaluation's set-up
(`evaluation.baselines.linemod.LineModIndex`: its feature counts, pyramid, padding and threshold), then its k best.
Both run on one thread. LineMOD's templates are added incrementally, so the largest count costs one
build; counts above `linemod_max_objects` are not measured for LineMOD and are listed as capped."""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial

import numpy as np
from tqdm import tqdm

from benchmarks.objects import ObjectSet
from benchmarks.stores.build import flat_snapshot
from benchmarks.timing import measure, ratio
from index.features.embed import Embedder
from index.store import Snapshot


@dataclass(frozen=True)
class RecognitionConfig:
    counts: tuple[int, ...] = (8, 100, 1000)  # objects in the store
    linemod_max_objects: int = 1000  # LineMOD above this is not measured (its build is ~0.6 ms/template)
    queries: int = 200  # timed recognitions, ours
    linemod_repeats: int = 5  # timed matches, LineMOD (seconds each at 1,000 objects)
    k: int = 5  # neighbours, as the service's default


def run(objects: ObjectSet, embedder: Embedder, embed_setup: Embedder, cfg: RecognitionConfig) -> dict:
    """`embedder` is timed (the service's threads); `embed_setup` makes the templates' descriptors."""
    from evaluation.baselines.linemod import LineModIndex, top_k

    modality = embedder.modality
    counts = sorted(c for c in cfg.counts if c <= objects.capacity)
    out: dict = {
        "modality": modality,
        "templates_per_object": objects.templates_per_object,
        "k": cfg.k,
        "query": "one rendered patch through the sensor model on a random background (shape 0, az 37, el 33)",
        "by_objects": {},
        "capped": [],
    }
    if len(counts) < len(cfg.counts):
        out["capped"].append(f"object counts above {objects.capacity} skipped: {len(objects.rgb)} shapes")
    rgb = objects.query_rgb if modality in ("rgb", "rgbd") else None
    depth = objects.query_depth if modality in ("depth", "rgbd") else None
    nominal = 400.0

    t0 = time.perf_counter()
    with tqdm(
        total=max(counts), desc=f"ours: embed templates ({modality})", unit="object", disable=None
    ) as bar:
        objects.embed_all(embed_setup, max(counts), bar.update)
    sets = [objects.template_set(embed_setup, j) for j in range(max(counts))]
    out["ours_embed_templates_s"] = time.perf_counter() - t0

    def embed_query() -> np.ndarray:
        return embedder.embed_patches(
            None if rgb is None else rgb[None], None if depth is None else depth[None], nominal, fill=True
        )

    def embed_and_search(snap: Snapshot) -> object:
        return snap.search(modality, embed_query(), cfg.k)

    t_embed = measure(embed_query, cfg.queries, warmup=3)  # the same at every store size
    query = embed_query()
    lm = LineModIndex(modality, objects.window_mm)
    lm_added, lm_build_s = 0, 0.0
    for n in counts:
        snap = flat_snapshot(modality, sets[:n])
        t_ours = measure(partial(embed_and_search, snap), cfg.queries, warmup=3)
        t_search = measure(partial(snap.search, modality, query, cfg.k), cfg.queries)
        (best, *_), *_ = snap.search(modality, query, cfg.k)
        row: dict = {
            "templates": int(snap.models[modality].size),
            "ours": t_ours.ms()
            | {"embed_median_ms": t_embed.median * 1e3, "search_median_ms": t_search.median * 1e3},
            "ours_top1_object": best.object_id - 1,  # object 0 is the query's
        }
        if n <= cfg.linemod_max_objects:
            t1 = time.perf_counter()
            total = n * objects.templates_per_object - lm_added * objects.templates_per_object
            with tqdm(total=total, desc=f"linemod: {n} objects", unit="template", disable=None) as bar:
                for j in range(lm_added, n):
                    t = objects.templates(j)
                    lm.add(
                        np.full(len(t.views), j),
                        t.rgb if modality in ("rgb", "rgbd") else None,
                        t.depth if modality in ("depth", "rgbd") else None,
                        t.depth > 0,
                        nominal,
                        progress=bar.update,
                    )
            lm_added, lm_build_s = n, lm_build_s + time.perf_counter() - t1

            def linemod() -> tuple[np.ndarray, np.ndarray]:
                return top_k(lm.similarities(rgb, depth, nominal), cfg.k)

            t_lm = measure(linemod, cfg.linemod_repeats, warmup=1)
            idx, _ = linemod()
            row["linemod"] = t_lm.ms() | {"build_s": lm_build_s, "templates_skipped": lm.skipped}
            row["linemod_top1_object"] = int(idx[0]) // objects.templates_per_object if idx[0] >= 0 else None
            row["speedup"] = ratio(t_lm.median, t_ours.median)
        else:
            out["capped"].append(
                f"linemod at {n} objects not measured (linemod_max_objects {cfg.linemod_max_objects})"
            )
        out["by_objects"][str(n)] = row
    return out
