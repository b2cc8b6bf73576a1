"""`POST /objects` of a 20k-face mesh against the real service, split into render / embed / store.

The mesh is `benchmarks.serving.costs.mesh_20k` (a 20,480-face ellipsoid with random vertex colours plus the
demo robot), uploaded as binary PLY; the service registers it for every model it loaded, at its template
settings, into the benchmark's store (so "store" includes copying indexes of that size; their snapshot
files are written after the answer). The first registration (shader compilation on the service's render
thread) is reported apart as `cold_s`; each object is deleted again, so every repetition meets the same
store. The split comes from the response: render (the render thread's seconds) and embed (the seconds
some embedding ran) overlap (chunks), so they add up to more than the total. With the service's process
id, the CPU seconds it spent from the upload to the answer (`cpu_s`, every thread: less at the mercy of
other work on the machine than the wall time). The window the service chose for the mesh's size
(`index.templates.windows`) and the diameter it read are reported with the times."""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

import httpx
from tqdm import tqdm


def _cpu(pid: int | None) -> float | None:
    """CPU seconds (user + system, every thread) of process `pid` so far; None without one (Linux)."""
    if pid is None:
        return None
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _register(c: httpx.Client, ply: bytes, pid: int | None) -> tuple[float, dict[str, float], dict]:
    cpu0 = _cpu(pid)
    t0 = time.perf_counter()
    r = c.post(
        "/objects",
        data={"name": "bench-20k", "units": "mm", "symmetry": "none"},
        files={"mesh": ("bench.ply", ply)},
    )
    if r.status_code == 202:  # over the service's sync window: follow the job (no split then)
        job = r.json()["job_id"]
        while (body := c.get(f"/jobs/{job}").json())["status"] == "running":
            time.sleep(0.05)
        if body["status"] != "done":
            raise RuntimeError(f"registration failed: {body}")
        wall, timings, oid = time.perf_counter() - t0, {}, body["object_id"]
        body = body.get("result") or {}  # what a 201 would have answered
    else:
        r.raise_for_status()
        body = r.json()
        wall, timings, oid = time.perf_counter() - t0, body["timings"], body["object_id"]
    if cpu0 is not None and (cpu1 := _cpu(pid)) is not None:
        timings = {**timings, "cpu": cpu1 - cpu0}
    c.delete(f"/objects/{oid}").raise_for_status()
    return wall, timings, body


def run(url: str, repeats: int, pid: int | None = None) -> dict:
    """`pid`: the service's process, for the CPU seconds a registration takes it (`cpu_s`: every thread,
    from the upload to the answer; what the other work on the machine cannot stretch as it does the wall
    time)."""
    from benchmarks.serving.costs import mesh_20k

    mesh = mesh_20k()
    ply = mesh.export(file_type="ply")
    assert isinstance(ply, bytes)  # binary PLY
    with httpx.Client(base_url=url, timeout=600) as c:
        ready = c.get("/readyz").json()
        cold, cold_split, created = _register(c, ply, pid)
        runs = [
            _register(c, ply, pid)[:2] for _ in tqdm(range(repeats), desc="HTTP: POST /objects", disable=None)
        ]
    walls = [w for w, _ in runs]
    stages = sorted({k for _, t in runs for k in t})
    out: dict = {
        "faces": len(mesh.faces),
        "upload_bytes": len(ply),
        "models": sorted(ready.get("models") or {}),
        "store_objects": ready.get("objects"),
        "store_templates": ready.get("templates"),
        "repeats": repeats,
        "cold_s": cold,
        "cold_split_s": cold_split,  # the first one's render / embed / store / total
        "wall_s": statistics.median(walls),
        "wall_min_s": min(walls),
        # the window the mesh's size chose (the model's for a mesh about its size) and its diameter, mm
        "window_mm": created.get("window_mm"),
        "diameter_mm": created.get("diameter_mm"),
    }
    for k in stages:
        vals = [t[k] for _, t in runs if k in t]
        out[f"{k}_s"] = statistics.median(vals) if vals else None
    if out.get("total_s") is not None:
        out["upload_and_parse_s"] = out["wall_s"] - out["total_s"]  # HTTP, multipart, mesh loading
    return out
