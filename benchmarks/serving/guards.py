"""`posedesc bench --only guards`: how long the service's guards take to refuse what they refuse. The tests
check the answers (tests/promises/test_hostile_uploads_refused.py, tests/index/templates/test_mesh_limits.py,
tests/index/templates/test_mesh_fuzz.py, tests/promises/test_loopback_unless_a_key.py); the times live here, as figures, since a
test must not fail on a slow machine.

- uploads: each of `benchmarks.serving.hostile.UPLOADS` sent to the real service (`posedesc serve` on loopback,
  level 1) and timed from the request to its 4xx; the answer's status beside the expected one;
- declaring: `load_mesh` refusing a file from what it declares (`benchmarks.serving.hostile.DECLARING`), before
  parsing (parsing these took trimesh 6-84 s);
- fuzz: `load_mesh` on damaged files of every format (`benchmarks.serving.hostile.damage`, seeded), per case:
  loaded or refused with MeshError, and anything else counted apart (a 500 in the service);
- busy port: `posedesc serve` on a port already taken, from the command to its one-line error (exit 2)."""

from __future__ import annotations

import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import httpx
import numpy as np
from tqdm import tqdm

from benchmarks.serving.hostile import DECLARING, UPLOADS, damage, png_claiming, random_damage, valid_mesh
from benchmarks.serving.server import Server
from benchmarks.timing import ROOT, Timing, measure
from index.templates.mesh import MESH_FORMATS, MeshError, MeshTooLarge, load_mesh

MAX_UPLOAD_FACES = 500_000  # the limits the fuzz and declaring cases are loaded with, as in their tests
MAX_FACES = 200_000


@dataclass(frozen=True)
class GuardsConfig:
    repeats: int = 3  # timed runs of each upload, declaring case and busy-port start
    large_repeats: int = 1  # of the uploads of tens of MB (`Upload.small` False): seconds each
    fuzz_cases: int = 300  # as many as the fuzz test's examples
    small_only: bool = False  # only the uploads cheap to make and send (the quick mode)
    seed: int = 0


def run(cfg: GuardsConfig, models: Path) -> dict:
    return {
        "declaring": _declaring(cfg),
        "fuzz": _fuzz(cfg),
        "busy_port": _busy_port(cfg, models),
        "uploads": _uploads(cfg, models),
    }


def _ms(t: Timing) -> dict:
    return {"median_ms": t.median * 1e3, "max_ms": max(t.seconds) * 1e3, "runs": len(t.seconds)}


def _declaring(cfg: GuardsConfig) -> dict:
    out = {}
    for name, (make, fmt, what) in tqdm(DECLARING.items(), desc="guards: declaring", disable=None):
        data = make()
        said: list[str] = []
        t = measure(partial(_refusal, data, fmt, said), cfg.repeats, warmup=0)
        out[name] = {"format": fmt, "bytes": len(data), "refused": f"declares {what}" in said[-1]} | _ms(t)
    return out


def _refusal(data: bytes, fmt: str, said: list[str]) -> None:
    """Appends what `load_mesh` says when it refuses the file as too large ("" when it does not)."""
    try:
        load_mesh(data, file_type=fmt, max_input_faces=MAX_UPLOAD_FACES)
    except MeshTooLarge as e:
        said.append(str(e))
    else:
        said.append("")


def _fuzz(cfg: GuardsConfig) -> dict:
    rng = np.random.default_rng(cfg.seed)
    formats = [f for f in MESH_FORMATS if f != "gltf"]  # glTF points at buffers: as GLB, in one file
    valid = {f: valid_mesh(f) for f in formats}
    seconds: dict[str, list[float]] = {f: [] for f in formats}
    outcome = {"loaded": 0, "refused": 0, "other_error": 0}
    others: list[str] = []
    for _ in tqdm(range(cfg.fuzz_cases), desc="guards: fuzz", unit="case", disable=None):
        fmt = formats[int(rng.integers(len(formats)))]
        data = damage(valid[fmt], random_damage(rng))
        t0 = time.perf_counter()
        try:
            load_mesh(data, file_type=fmt, max_faces=MAX_FACES, max_input_faces=MAX_UPLOAD_FACES)
            outcome["loaded"] += 1
        except MeshError:
            outcome["refused"] += 1
        except Exception as e:  # what the fuzz test would fail on: reported, not raised
            outcome["other_error"] += 1
            others.append(f"{fmt}: {type(e).__name__}: {e}"[:200])
        seconds[fmt].append(time.perf_counter() - t0)
    every = Timing(tuple(s for v in seconds.values() for s in v))
    return {
        "cases": cfg.fuzz_cases,
        **outcome,
        "other_errors": others[:10],
        "p50_ms": every.percentile(50) * 1e3,
        "p99_ms": every.percentile(99) * 1e3,
        "max_ms": max(every.seconds) * 1e3,
        "by_format_max_ms": {f: max(v) * 1e3 for f, v in seconds.items() if v},
    }


def _busy_port(cfg: GuardsConfig, models: Path) -> dict:
    codes: list[int] = []
    with socket.socket() as taken, tempfile.TemporaryDirectory(prefix="posedesc-bench-") as tmp:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        cmd = [sys.executable, "-m", "posedesc.cli", "serve", "--host", "127.0.0.1", "--port", str(port)]
        cmd += ["--data-dir", str(Path(tmp) / "data"), "--models", str(models)]

        def start() -> None:
            codes.append(subprocess.run(cmd, cwd=ROOT, capture_output=True, timeout=600).returncode)

        t = measure(start, cfg.repeats, warmup=0)
    return {
        "exit_codes": sorted(set(codes)),
        "median_s": t.median,
        "max_s": max(t.seconds),
        "runs": cfg.repeats,
    }


def _uploads(cfg: GuardsConfig, models: Path) -> dict:
    cases = {k: u for k, u in UPLOADS.items() if u.small or not cfg.small_only}
    env = {"POSEDESC_DEMO_OBJECTS": "false", "POSEDESC_LEVEL": "1", "POSEDESC_API_KEY": ""}
    out: dict = {}
    with (
        tempfile.TemporaryDirectory(prefix="posedesc-bench-") as tmp,
        Server(Path(tmp) / "data", models, env) as url,
        httpx.Client(base_url=url, timeout=600) as c,
    ):
        c.post("/recognize", files={"rgb": ("a.png", png_claiming(64, 64))})  # warm-up, not timed
        for name, u in tqdm(cases.items(), desc="guards: hostile uploads", disable=None):
            content = u.make()
            endpoint, data = ("/objects", {"name": "hostile"}) if u.field == "mesh" else ("/recognize", {})
            statuses: list[int] = []

            def send(content=content, u=u, endpoint=endpoint, data=data, statuses=statuses) -> None:
                r = c.post(endpoint, files={u.field: (u.filename, content)}, data=data)
                statuses.append(r.status_code)

            t = measure(send, cfg.repeats if u.small else cfg.large_repeats, warmup=0)
            out[name] = {"bytes": len(content), "status": statuses[-1], "expected": u.status} | _ms(t)
    return out
