"""`POST /recognize` over HTTP on loopback: latency p50 / p99 and requests per second with 1, 4, 8 ...
concurrent clients against the real service (`benchmarks.server`), each client its own keep-alive
connection (httpx) on its own thread, all started together.

The request is the query patch (PNG, the modality's images), the smallest a client can send; a
640x480 frame (the README's demo robot, PNGs to decode, a patch to cut) is timed too, one client."""

from __future__ import annotations

import io
import statistics
import threading
import time
from dataclasses import dataclass

import httpx
import numpy as np
from PIL import Image
from tqdm import tqdm

from benchmarks.objects import ObjectSet
from benchmarks.timing import Timing


@dataclass(frozen=True)
class HttpConfig:
    objects: int = 100  # registered objects the service searches
    concurrency: tuple[int, ...] = (1, 4, 8)
    requests: int = 400  # per concurrency level and round
    rounds: int = 3
    warmup: int = 20


def png(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="PNG")
    return buf.getvalue()


@dataclass
class Request:
    files: dict[str, tuple[str, bytes]]
    data: dict[str, str]


def patch_request(objects: ObjectSet, modality: str) -> Request:
    files = {}
    if modality in ("rgb", "rgbd"):
        files["rgb"] = ("rgb.png", png(objects.query_rgb))
    if modality in ("depth", "rgbd"):
        files["depth"] = ("depth.png", png(np.round(objects.query_depth).astype(np.uint16)))
    return Request(files, {"k": "5"})


def frame_request(modality: str) -> Request:
    from benchmarks.serving import demo_frame
    from index.render import RenderWorker

    worker = RenderWorker()
    try:
        rgb, depth, fields = demo_frame(worker)
    finally:
        worker.close()
    files, data = {}, {k: str(v) for k, v in fields.items()} | {"k": "5"}
    if modality in ("rgb", "rgbd"):
        files["rgb"] = ("rgb.png", png(rgb))
    if modality in ("depth", "rgbd"):
        files["depth"] = ("depth.png", png(np.round(depth).astype(np.uint16)))
    if modality == "rgb":
        data["distance_mm"] = "600"
    return Request(files, data)


def load(url: str, req: Request, concurrency: int, total: int) -> tuple[list[float], list[float], float, int]:
    """`total` requests from `concurrency` clients at once: (latencies s, server-side totals ms, wall s,
    failed requests)."""
    per = max(1, total // concurrency)
    latencies: list[float] = []
    inner: list[float] = []
    failed = [0]
    start = threading.Barrier(concurrency + 1)

    def client() -> None:
        with httpx.Client(base_url=url, timeout=120) as c:
            c.get("/healthz")  # connect before the clock starts
            start.wait()
            for _ in range(per):
                t0 = time.perf_counter()
                r = c.post("/recognize", files=req.files, data=req.data)
                latencies.append(time.perf_counter() - t0)
                if r.status_code == 200:
                    inner.append(float(r.json()["timings_ms"]["total"]))
                else:
                    failed[0] += 1

    threads = [threading.Thread(target=client, daemon=True) for _ in range(concurrency)]
    for t in threads:
        t.start()
    start.wait()
    t0 = time.perf_counter()
    for t in threads:
        t.join()
    return latencies, inner, time.perf_counter() - t0, failed[0]


def run(url: str, objects: ObjectSet, modality: str, cfg: HttpConfig) -> dict:
    patch = patch_request(objects, modality)
    load(url, patch, 1, cfg.warmup)
    out: dict = {
        "objects": cfg.objects,
        "modality": modality,
        "request": "the query patch as PNG, k = 5",
        "requests_per_level": cfg.requests,
        "rounds": cfg.rounds,
        "by_concurrency": {},
    }
    levels = [(c, r) for c in cfg.concurrency for r in range(cfg.rounds)]
    results: dict[int, list] = {}
    for c, _ in tqdm(levels, desc="HTTP: /recognize", unit="round", disable=None):
        results.setdefault(c, []).append(load(url, patch, c, cfg.requests))
    for c, rounds in results.items():
        latency = Timing(tuple(x for r in rounds for x in r[0]))
        inner = [x for r in rounds for x in r[1]]
        out["by_concurrency"][str(c)] = latency.ms() | {
            "requests_per_s": statistics.median(len(r[0]) / r[2] for r in rounds),
            "server_total_median_ms": statistics.median(inner) if inner else None,
            "failed": sum(r[3] for r in rounds),
        }
    frame = frame_request(modality)
    load(url, frame, 1, cfg.warmup // 4 + 1)
    lat, inner, wall, failed = load(url, frame, 1, max(10, cfg.requests // 4))
    out["frame_640x480"] = Timing(tuple(lat)).ms() | {
        "requests_per_s": len(lat) / wall,
        "server_total_median_ms": statistics.median(inner) if inner else None,
        "failed": failed,
        "request": "README's demo frame: " + "+".join(frame.files) + " PNGs, camera fields, k = 5",
    }
    return out
