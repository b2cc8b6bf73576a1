"""What a registered object costs in memory (section "memory", opt-in: `posedesc bench --only memory`): the
resident memory of the state `posedesc serve` loads (`service.state.load_state`, every model of the models
dir) from a data dir of N objects, after one query per model, at each count; the slope between the counts
is the memory one more object costs. Beside it the accounting (`accounting`): every array the store holds
per object and model, its shape, dtype and bytes in RAM (anonymous, or mapped from a file) and on disk.

How the stores are made: one procedural shape (`benchmarks.objects.shapes`) is registered by the service's
own code (`index.templates.register.make_templates` then `Store.add_object`: every model, in-plane templates, local
features, silhouettes and reliefs); objects 2..N are copies of its SQLite rows under new object ids, one
bulk SQL statement (registering 1,000 objects by rendering would take an hour, and through
`Store.add_object` rewrite every index snapshot once per object). A copy costs what an object costs: its
descriptors enter FAISS, its local features the store, each on their own. The store is then opened once
(its index snapshots and local feature files made from SQLite, as at a restart) before it is measured.

Each count is measured in a fresh process (`python -m benchmarks.stores.memory`), which reports /proc's VmRSS,
RssAnon (heap: what the process holds) and RssFile (pages of mapped files: page cache the kernel may drop
and read again), at three moments: the models loaded on an empty store, the store loaded, one query per
model answered."""

from __future__ import annotations

import gc
import json
import mmap
import os
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import faiss
import numpy as np

from benchmarks.timing import ROOT

#: /proc/self/status fields reported, kB there
RSS_FIELDS = ("VmRSS", "RssAnon", "RssFile", "VmHWM")


@dataclass(frozen=True)
class MemoryConfig:
    counts: tuple[int, ...] = (100, 1000)  # objects in the stores measured (the issue's)
    level: int = 3  # template viewpoints (3: the paper's 301), as the service's default


def rss() -> dict[str, int]:
    """This process's resident memory now (bytes), by /proc/self/status's fields `RSS_FIELDS`."""
    out = {}
    for line in Path("/proc/self/status").read_text().splitlines():
        key, _, value = line.partition(":")
        if key in RSS_FIELDS:
            out[key] = int(value.split()[0]) * 1024
    return out


def one_object(models_dir: Path, level: int, seed: int = 0) -> tuple[dict[str, tuple[int, str]], dict]:
    """The store keys of the models in `models_dir` and one procedural shape's template sets for all of
    them, made by the registration's own code (`index.templates.register.make_templates`)."""
    from benchmarks.objects import shapes
    from index.features.embed import load_models, store_keys
    from index.templates.register import TemplateConfig, make_templates, model_views
    from index.templates.render import RenderWorker

    embedders = load_models(models_dir, threads=2)
    views = model_views("none", TemplateConfig(level=level), embedders)
    sizes = {e.info.size for e in embedders.values()}
    worker = RenderWorker(size=sizes.pop(), window_mm=min(e.info.window_mm for e in embedders.values()))
    try:
        sets, _, _ = make_templates(worker, embedders, shapes(1, seed)[0], views)
    finally:
        worker.close()
    return store_keys(embedders), sets


def fill(data_dir: Path, models: Mapping[str, tuple[int, str]], sets: Mapping, n: int) -> None:
    """A data dir of `n` objects: object 1 added by `Store.add_object`, 2..n copies of its SQLite rows
    (one transaction), then the store opened once so that its snapshot files exist."""
    from index.store import Store

    store = Store(data_dir, models)
    try:
        oid = store.add_object("object-1", "none", sets, extra={"benchmark": True}).object_id
    finally:
        store.close()
    db = sqlite3.connect(data_dir / "store.sqlite", isolation_level=None)
    try:
        db.execute("BEGIN IMMEDIATE")
        # the object's rows once in a table of their own: a copy per object then reads them alone
        db.execute("CREATE TEMP TABLE one AS SELECT * FROM templates WHERE object_id = ? ORDER BY id", (oid,))
        for j in range(2, n + 1):
            cur = db.execute(
                "INSERT INTO objects (name, symmetry, faces, created, extra, mesh) "
                "SELECT ?, symmetry, faces, created, extra, mesh FROM objects WHERE id = ?",
                (f"object-{j}", oid),
            )
            db.execute(
                "INSERT INTO templates (object_id, model, azimuth, elevation, inplane, descriptor, local) "
                "SELECT ?, model, azimuth, elevation, inplane, descriptor, local FROM one ORDER BY rowid",
                (cur.lastrowid,),
            )
        db.execute("UPDATE meta SET value = CAST(value AS INTEGER) + 1 WHERE key = 'generation'")
        db.execute("COMMIT")
    finally:
        db.close()
    Store(data_dir, models).close()  # snapshot files made from SQLite, as a restart would


def _distinct_bytes(arrays: list[np.ndarray]) -> tuple[int, int]:
    """Bytes of these arrays' memory counted once each (views of one buffer, a buffer two models share):
    (anonymous, mapped from a file)."""
    seen: dict[int, tuple[int, bool]] = {}
    for a in arrays:
        root: object = a
        while isinstance(root, np.ndarray) and root.base is not None:
            root = root.base
        mapped = isinstance(root, mmap.mmap)
        seen[a.__array_interface__["data"][0]] = (a.nbytes, mapped)
    anon = sum(b for b, m in seen.values() if not m)
    return anon, sum(b for b, m in seen.values() if m)


def _faiss_bytes(index: faiss.Index) -> int:
    """An index's memory: its vectors, and for an id map its ids (8 bytes each) and, for IndexIDMap2, the
    reverse map (a hash map: ~40 bytes an entry, estimated from libstdc++'s node and bucket)."""
    vectors = index.ntotal * index.d * 4
    if isinstance(index, faiss.IndexIDMap2):
        return vectors + index.ntotal * (8 + 40)
    if isinstance(index, faiss.IndexIDMap):
        return vectors + index.ntotal * 8
    return vectors + index.ntotal * 8  # IVF: the list ids


def accounting(data_dir: Path, models: Mapping[str, tuple[int, str]]) -> dict:
    """Per object and model (the store's totals / its objects): each array's shape, dtype and bytes in RAM
    (anonymous or file-mapped; memory two models share counted once, under the first) and on disk (SQLite
    blobs, snapshot files), from the store `data_dir` holds, opened as the service opens it."""
    from index.store import Store

    store = Store(data_dir, models)
    try:
        snap = store.snapshot
        n = max(1, len(snap.objects))
        db = sqlite3.connect(data_dir / "store.sqlite")
        blobs = {
            m: (int(d or 0), int(loc or 0), int(rows))
            for m, d, loc, rows in db.execute(
                "SELECT model, SUM(length(descriptor)), SUM(length(local)), COUNT(*) FROM templates GROUP BY model"
            )
        }
        db.close()
        out: dict = {"objects": len(snap.objects), "models": {}}
        seen_index: dict[int, str] = {}
        seen_local: list[np.ndarray] = []
        for m, mi in snap.models.items():
            per = mi.size // n
            shared = seen_index.get(id(mi))  # a model sharing an earlier one's index (`same_as`)
            seen_index.setdefault(id(mi), m)
            rows = list(mi.local.values())
            before = _distinct_bytes(seen_local)
            seen_local += rows
            after = _distinct_bytes(seen_local)
            local_anon, local_mapped = after[0] - before[0], after[1] - before[1]
            entry: dict = {
                "templates": per,
                "descriptors": {
                    "shape": [per, mi.index.d],
                    "dtype": "float32",
                    "ram_bytes": 0 if shared else _faiss_bytes(mi.index) // n,
                    "shared_with": shared,
                    "index": type(mi.index).__name__,
                },
                "ids_object_ids_poses": {
                    "shape": [per, 1 + 1 + 3],
                    "dtype": f"{mi.ids.dtype}, {mi.object_ids.dtype}, {mi.poses.dtype}",
                    "ram_bytes": 0
                    if shared
                    else (mi.ids.nbytes + mi.object_ids.nbytes + mi.poses.nbytes) // n,
                },
            }
            if rows:
                entry["local"] = {
                    "shape": [len(rows) // n, rows[0].shape[-1]],
                    "dtype": str(rows[0].dtype),
                    "parts": "features, silhouette cells, relief cells (index.features.local.StoredLocal)",
                    "ram_anonymous_bytes": local_anon // n,
                    "ram_mapped_bytes": local_mapped // n,
                    "python_objects_bytes": 0 if shared else _dict_overhead(mi.local) // n,
                }
            d, loc, _ = blobs.get(m, (0, 0, 0))
            entry["disk"] = {"sqlite_descriptor_bytes": d // n, "sqlite_local_bytes": loc // n}
            out["models"][m] = entry
        files: dict[str, int] = {}
        inodes: set[tuple[int, int]] = set()
        for p in sorted(data_dir.rglob("*")):
            if p.is_file():
                st = p.stat()
                if (st.st_dev, st.st_ino) in inodes:  # a hard link: the same bytes
                    continue
                inodes.add((st.st_dev, st.st_ino))
                kind = "sqlite" if p.name.startswith("store.sqlite") else p.suffix.lstrip(".") or p.name
                files[kind] = files.get(kind, 0) + st.st_size
        out["disk_bytes_per_object"] = {k: v // n for k, v in files.items()}
        out["disk_bytes_per_object"]["total"] = sum(files.values()) // n
        ram = 0
        for e in out["models"].values():
            ram += e["descriptors"]["ram_bytes"] + e["ids_object_ids_poses"]["ram_bytes"]
            if "local" in e:
                ram += e["local"]["ram_anonymous_bytes"] + e["local"]["python_objects_bytes"]
        out["ram_anonymous_bytes_per_object"] = ram
        out["ram_mapped_bytes_per_object"] = sum(
            e["local"]["ram_mapped_bytes"] for e in out["models"].values() if "local" in e
        )
    finally:
        store.close()
    return out


def _dict_overhead(local: Mapping) -> int:
    """Python objects of a local-feature mapping: its table, keys and array headers (not their data)."""
    if not local:
        return 0
    key, value = next(iter(local.items()))
    per = sys.getsizeof(key) + sum(sys.getsizeof(x) for x in key) + _header(value)
    return sys.getsizeof(local) + per * len(local)


def _header(a: np.ndarray) -> int:
    """An array object's own size without its data (a view's: ~112 bytes; a memmap view carries more)."""
    return sys.getsizeof(a) - (a.nbytes if a.base is None else 0)


def measure(data_dir: Path, models_dir: Path, query: Path, level: int) -> dict:
    """In a fresh process: the resident memory with the models loaded (an empty store), then the state
    `posedesc serve` loads from `data_dir`, then after one query per model (`query`: PNG files as a user
    sends them). Returns the `rss` readings and the seconds the store took to load."""
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "benchmarks.stores.memory",
            str(data_dir),
            str(models_dir),
            str(query),
            str(level),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)},
        check=False,
    )
    if out.returncode != 0:
        raise RuntimeError(f"the memory probe failed: {out.stderr.strip().splitlines()[-1:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _probe(data_dir: Path, models_dir: Path, query: Path, level: int) -> dict:
    """What `measure` runs in its process."""
    from index.features.embed import load_models
    from service.pipeline.query import Query
    from service.recognition import recognise
    from service.settings import Settings
    from service.state import close_state, load_state

    embedders = load_models(models_dir, threads=1)
    out: dict = {"models": rss()}
    settings = Settings(data_dir=data_dir, models_dir=models_dir, demo_objects=False, threads=1, level=level)
    t0 = time.perf_counter()
    state = load_state(settings, embedders)
    out["load_s"] = round(time.perf_counter() - t0, 2)
    try:
        gc.collect()
        out["loaded"] = rss()
        files = dict(np.load(query))
        for m in state.embedders:
            q = Query(
                rgb=files["rgb"].tobytes() if m in ("rgb", "rgbd") else None,
                depth=files["depth"].tobytes() if m in ("depth", "rgbd") else None,
                k=5,
            )
            result = recognise(state, q)
            out.setdefault("top1", {})[m] = result.matches[0].object_id if result.matches else None
        gc.collect()
        out["queried"] = rss()
    finally:
        close_state(state)
    return out


def _query_file(path: Path, seed: int) -> None:
    """The query patch (shape 0 seen through the sensor model on a background) as the PNGs a user sends."""
    from benchmarks.objects import render_objects
    from benchmarks.serving.over_http import png

    objects = render_objects(1, level=0, seed=seed)
    rgb = np.frombuffer(png(objects.query_rgb), np.uint8)
    depth = np.frombuffer(png(np.round(objects.query_depth).astype(np.uint16)), np.uint8)
    np.savez(path, rgb=rgb, depth=depth)


def run(cfg: MemoryConfig, models_dir: Path, seed: int = 0) -> dict:
    """The section: per count, the accounting and the resident memory; the slopes between counts."""
    t0 = time.perf_counter()
    models, sets = one_object(models_dir, cfg.level, seed)
    out: dict = {
        "config": {"counts": list(cfg.counts), "level": cfg.level},
        "how": __doc__.split("\n\n")[1].replace("\n", " "),
        "templates_per_object": {m: len(ts.poses) for m, ts in sets.items()},
        "make_one_object_s": round(time.perf_counter() - t0, 1),
        "by_count": {},
    }
    with tempfile.TemporaryDirectory(prefix="posedesc-memory-") as tmp:
        query = Path(tmp) / "query.npz"
        _query_file(query, seed)
        for n in cfg.counts:
            data = Path(tmp) / f"objects-{n}"
            t1 = time.perf_counter()
            fill(data, models, sets, n)
            fill_s = time.perf_counter() - t1
            probe = measure(data, models_dir, query, cfg.level)
            out["by_count"][str(n)] = {
                "fill_s": round(fill_s, 1),
                "accounting": accounting(data, models),
                **probe,
            }
            shutil.rmtree(data)  # 1,000 objects take gigabytes
    counts = sorted(cfg.counts)
    if len(counts) > 1:
        lo, hi = out["by_count"][str(counts[0])], out["by_count"][str(counts[-1])]
        span = counts[-1] - counts[0]
        out["slope_mb_per_object"] = {
            f"{moment}_{key}": round((hi[moment][key] - lo[moment][key]) / span / 1e6, 3)
            for moment in ("loaded", "queried")
            for key in ("VmRSS", "RssAnon", "RssFile")
        }
        out["disk_mb_per_object"] = round(
            (hi["accounting"]["disk_bytes_per_object"]["total"] * counts[-1]
             - lo["accounting"]["disk_bytes_per_object"]["total"] * counts[0]) / span / 1e6,
            3,
        )  # fmt: skip
    return out


if __name__ == "__main__":
    print(json.dumps(_probe(Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]), int(sys.argv[4]))))
