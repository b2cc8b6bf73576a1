"""`POST /recognize` over HTTP on loopback: latency p50 / p99 and requests per second with 1, 4, 8 ...
concurrent clients against the real service (`benchmarks.serving.server`), each client its own keep-alive
connection on its own thread, all started together.

The request is the query patch (PNG, the modality's images), the smallest a client can send; a
640x480 frame (the README's demo robot, PNGs to decode, a patch to cut) is timed too, one client.

The clients run on the server's cores, so they are made light: the multipart body is encoded once
(`Request.encoded`, by httpx, as it would send it) and sent by the standard library's `http.client`.
An httpx client encoding the form for each request took ~3 ms of CPU a request against ~0.6 ms (this
2-core machine, the demo frame), time the latency counted as the service's."""

from __future__ import annotations

import http.client
import io
import json
import statistics
import threading
import time
from dataclasses import dataclass
from urllib.parse import urlsplit

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

    def encoded(self) -> tuple[bytes, dict[str, str]]:
        """The multipart body of `POST /recognize` with these files and fields, and its headers."""
        r = httpx.Request("POST", "http://localhost/recognize", files=self.files, data=self.data)
        body = r.read()
        return body, {"Content-Type": r.headers["Content-Type"], "Content-Length": str(len(body))}


def patch_request(objects: ObjectSet, modality: str) -> Request:
    files = {}
    if modality in ("rgb", "rgbd"):
        files["rgb"] = ("rgb.png", png(objects.query_rgb))
    if modality in ("depth", "rgbd"):
        files["depth"] = ("depth.png", png(np.round(objects.query_depth).astype(np.uint16)))
    return Request(files, {"k": "5"})


def frame_request(modality: str) -> Request:
    from benchmarks.serving.costs import demo_frame
    from index.templates.render import RenderWorker

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


@dataclass(frozen=True)
class Load:
    """What `load` measured: every request's latency (s), the server's `timings_ms.total` (ms) of each that
    was answered and, for those, latency minus that total (`around_ms`: HTTP, the form, the answer's models
    and JSON, the hops to and from the recognition thread, and with more clients than recognitions run at
    once, the wait for a turn); wall seconds; requests not answered 200."""

    latencies: tuple[float, ...]
    server_ms: tuple[float, ...]
    around_ms: tuple[float, ...]
    wall_s: float
    failed: int

    @classmethod
    def joined(cls, rounds: list[Load]) -> Load:
        """Rounds as one: every request of each, their wall seconds added."""
        return cls(
            tuple(x for r in rounds for x in r.latencies),
            tuple(x for r in rounds for x in r.server_ms),
            tuple(x for r in rounds for x in r.around_ms),
            sum(r.wall_s for r in rounds),
            sum(r.failed for r in rounds),
        )

    def summary(self) -> dict:
        """The JSON form: latency percentiles, requests per second, the medians of the server's total and
        of what the request cost around it, failures."""
        return Timing(self.latencies).ms() | {
            "requests_per_s": len(self.latencies) / self.wall_s,
            "server_total_median_ms": statistics.median(self.server_ms) if self.server_ms else None,
            "around_median_ms": statistics.median(self.around_ms) if self.around_ms else None,
            "failed": self.failed,
        }


def load(url: str, req: Request, concurrency: int, total: int) -> Load:
    """`total` requests from `concurrency` clients at once."""
    per = max(1, total // concurrency)
    done: list[tuple[float, float | None]] = []  # (latency s, server total ms or None): one append each
    start = threading.Barrier(concurrency + 1)
    body, headers = req.encoded()
    where = urlsplit(url)

    def client() -> None:
        c = http.client.HTTPConnection(where.hostname or "127.0.0.1", where.port, timeout=120)
        try:
            c.request("GET", "/healthz")  # connect before the clock starts
            c.getresponse().read()
            start.wait()
            for _ in range(per):
                t0 = time.perf_counter()
                c.request("POST", "/recognize", body, headers)
                r = c.getresponse()
                answer = r.read()
                latency = time.perf_counter() - t0
                ok = r.status == 200
                done.append((latency, float(json.loads(answer)["timings_ms"]["total"]) if ok else None))
        finally:
            c.close()

    threads = [threading.Thread(target=client, daemon=True) for _ in range(concurrency)]
    for t in threads:
        t.start()
    start.wait()
    t0 = time.perf_counter()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    answered = [(s, ms) for s, ms in done if ms is not None]
    return Load(
        tuple(s for s, _ in done),
        tuple(ms for _, ms in answered),
        tuple(s * 1e3 - ms for s, ms in answered),
        wall,
        len(done) - len(answered),
    )


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
    results: dict[int, list[Load]] = {}
    for c, _ in tqdm(levels, desc="HTTP: /recognize", unit="round", disable=None):
        results.setdefault(c, []).append(load(url, patch, c, cfg.requests))
    for c, rounds in results.items():
        out["by_concurrency"][str(c)] = Load.joined(rounds).summary() | {
            "requests_per_s": statistics.median(len(r.latencies) / r.wall_s for r in rounds)
        }
    frame = frame_request(modality)
    load(url, frame, 1, cfg.warmup // 4 + 1)
    out["frame_640x480"] = load(url, frame, 1, max(10, cfg.requests // 4)).summary() | {
        "request": "README's demo frame: " + "+".join(frame.files) + " PNGs, camera fields, k = 5",
    }
    return out
