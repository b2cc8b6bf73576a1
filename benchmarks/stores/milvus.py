"""`posedesc bench --only milvus`: the template store through Milvus beside the embedded one (FAISS +
SQLite), at 100 objects (30,100 templates) and at larger stores (10^6 templates by default), and the
recall of Milvus's index (HNSW, `index.store.milvus`'s parameters) against exact search.

Measured through the stores' own interface, the calls a recognition and a registration make:
- recognition: `snapshot.answers(model, q, k)`, the k-NN and the collapse to distinct answers of
  `service.recognition` (no embedding: the descriptor is given), one query at a time, one thread;
- registration: `add_object` of one object of 301 templates (one model), as `index.templates.register.register`
  calls it after embedding, then `remove_object` (not timed);
- recall@k: Milvus's answers (`snapshot.search`, k templates) against the exact k nearest (FAISS flat);
- propagation: two stores on the one Milvus and one shared directory, as two replicas: how long until one
  store's snapshot shows the other's registration, and its deletion.

Descriptors are `benchmarks.stores.knn.Synthetic` (objects of 301 templates around their centres, 16 values) and
a query is a template plus noise. The 100-object stores are filled through `add_object`, object by object;
the larger ones in bulk (the embedded one as an in-memory snapshot, Milvus by inserting records and
templates in batches, then waiting until its index covers them), as registering 3,322 objects one by one
would take an hour. Milvus is the PyPI server (`benchmarks.stores.milvus_server`) on this machine unless `uri`
names one: same 2 cores, so its figures include the server's own work and the gRPC round trip."""

from __future__ import annotations

import json
import tempfile
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from benchmarks.stores.knn import TEMPLATES_PER_OBJECT, Synthetic
from benchmarks.timing import measure
from index.store import EmbeddedStore, set_threads
from index.store.records import ObjectRecord, TemplateSet
from index.store.search import FaissSnapshot, ModelIndex

MODEL = "rgb"


@dataclass(frozen=True)
class MilvusConfig:
    objects: int = 100  # the small store: filled object by object through add_object
    large: tuple[int, ...] = (10**6,)  # templates of the large stores (bulk-loaded)
    dim: int = 16
    k: int = 5
    queries: int = 200
    recall_queries: int = 200
    registrations: int = 5
    uri: str | None = None  # a running Milvus; None: the PyPI server, started for the run
    seed: int = 0


def poses(n: int) -> np.ndarray:
    """Template j of an object: azimuth j (a label that tells templates apart), elevation 30."""
    j = np.arange(n) % TEMPLATES_PER_OBJECT
    return np.stack([j.astype(np.float32), np.full(n, 30.0, np.float32), np.zeros(n, np.float32)], 1)


def object_sets(data: Synthetic) -> list[TemplateSet]:
    rows = np.concatenate([c for _, c in data.chunks()])
    p = poses(data.n)
    return [
        TemplateSet(p[s : s + TEMPLATES_PER_OBJECT], rows[s : s + TEMPLATES_PER_OBJECT])
        for s in range(0, data.n, TEMPLATES_PER_OBJECT)
    ]


def run(cfg: MilvusConfig) -> dict:
    from benchmarks.stores.milvus_server import LocalMilvus

    set_threads(1)
    out: dict = {
        "dim": cfg.dim,
        "k": cfg.k,
        "milvus_index": "HNSW (M 16, efConstruction 200), search ef max(128, n); Bounded reads",
        "embedded_index": "FAISS IndexIDMap2(IndexFlatL2), exact",
        "by_size": {},
    }
    with tempfile.TemporaryDirectory() as tmp:
        server = None
        uri = cfg.uri
        if uri is None:
            server = LocalMilvus(Path(tmp) / "milvus")
            server.start()
            uri = server.uri
        out["milvus"] = {"uri": "PyPI milvus 2.3.5 standalone on this machine" if server else uri}
        try:
            sizes = [cfg.objects * TEMPLATES_PER_OBJECT, *cfg.large]
            for n in tqdm(sizes, desc="milvus vs embedded: store sizes", unit="size", disable=None):
                before = _server_rss(server)
                row = _one_size(
                    cfg, uri, n, Path(tmp) / f"s{n}", bulk=n != sizes[0], rss=lambda: _server_rss(server)
                )
                row["milvus_server_rss_bytes_before"] = before
                out["by_size"][str(n)] = row
            out["propagation"] = _propagation(cfg, uri, Path(tmp) / "propagation")
        finally:
            if server is not None:
                server.stop()
    return out


def _server_rss(server) -> int | None:
    """The local Milvus process's resident memory (VmRSS), bytes; None for a remote one."""
    proc = getattr(getattr(server, "server", None), "server_proc", None)
    if proc is None:
        return None
    try:
        status = Path(f"/proc/{proc.pid}/status").read_text()
    except OSError:
        return None
    line = next((ln for ln in status.splitlines() if ln.startswith("VmRSS:")), None)
    return int(line.split()[1]) * 1024 if line else None


def _one_size(cfg: MilvusConfig, uri: str, n: int, tmp: Path, bulk: bool, rss=lambda: None) -> dict:
    from index.store.milvus import MilvusStore

    rng = np.random.default_rng([cfg.seed, n])
    data = Synthetic(n, cfg.dim, cfg.seed)
    sets = object_sets(data)
    nq = max(cfg.queries, cfg.recall_queries)
    queries = data.rows(rng.choice(data.n, nq, replace=False))
    queries += 0.05 * rng.standard_normal(queries.shape, dtype=np.float32)
    models = {MODEL: (cfg.dim, "bench")}
    row: dict = {"templates": n, "objects": len(sets), "filled": "bulk" if bulk else "add_object"}

    t0 = time.perf_counter()
    if bulk:
        embedded_snap = _faiss_snapshot(sets)
        embedded = None
    else:
        embedded = EmbeddedStore(tmp / "embedded", models)
        for j, s in enumerate(sets):
            embedded.add_object(f"object-{j + 1}", "none", {MODEL: s})
        embedded_snap = embedded.snapshot
    row["embedded_fill_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    milvus = MilvusStore(uri, tmp / "shared", models, prefix=f"bench{uuid.uuid4().hex[:8]}", timeout=120)
    try:
        if bulk:
            _bulk_load(milvus, sets)
        else:
            for j, s in enumerate(sets):
                milvus.add_object(f"object-{j + 1}", "none", {MODEL: s})
        row["milvus_fill_s"] = time.perf_counter() - t0
        milvus_snap = milvus.snapshot
        assert milvus_snap.models[MODEL].size == n, (milvus_snap.models[MODEL].size, n)

        order = iter(range(1 << 40))

        def answer(snap):
            return lambda: snap.answers(MODEL, queries[next(order) % cfg.queries][None], cfg.k)

        row["recognition"] = {
            "embedded": measure(answer(embedded_snap), cfg.queries, warmup=5).ms(),
            "milvus": measure(answer(milvus_snap), cfg.queries, warmup=5).ms(),
        }
        row["recall_at_k"] = _recall(milvus_snap, embedded_snap, queries[: cfg.recall_queries], cfg.k)
        new = TemplateSet(poses(TEMPLATES_PER_OBJECT), data.rows(np.arange(TEMPLATES_PER_OBJECT)) + 3.0)
        row["registration"] = {
            "milvus": _registrations(milvus, new, cfg.registrations),
            **({"embedded": _registrations(embedded, new, cfg.registrations)} if embedded else {}),
        }
        if not bulk:
            row["replica_start"] = _replica_start(milvus, uri, tmp / "shared", models, queries[:20], cfg.k)
        row["milvus_memory"] = _milvus_memory(milvus)
        row["milvus_server_rss_bytes_loaded"] = rss()  # with this store's collection loaded
    finally:
        milvus.client.drop_collection(milvus.collections[MODEL])
        milvus.client.drop_collection(milvus.objects_collection)
        milvus.close()
        if embedded is not None:
            embedded.close()
    return row


def _propagation(cfg: MilvusConfig, uri: str, shared: Path) -> dict:
    """Two stores on one Milvus and one shared directory, as two replicas of the service: an object added
    through one until the other's snapshot (what its recognitions search) holds it; removed through the
    other until the first's no longer does. Each from the call's start (the call itself waits for Milvus
    to show the change, so the other store may see it before the call returns), and how long the call
    took. `registrations` times each."""
    from index.store.milvus import MilvusStore

    models = {MODEL: (cfg.dim, "bench")}
    prefix = f"bench{uuid.uuid4().hex[:8]}"
    a = MilvusStore(uri, shared, models, prefix=prefix, timeout=120)
    b = MilvusStore(uri, shared, models, prefix=prefix, timeout=120)
    rows = Synthetic(TEMPLATES_PER_OBJECT, cfg.dim, cfg.seed).rows(np.arange(TEMPLATES_PER_OBJECT))
    ts = TemplateSet(poses(TEMPLATES_PER_OBJECT), rows)
    times: dict[str, list[tuple[float, float]]] = {"registration": [], "deletion": []}
    try:
        for i in tqdm(range(cfg.registrations), desc="milvus: replica propagation", disable=None):
            name = f"propagation-{i}"
            times["registration"].append(
                _seen(
                    lambda name=name: a.add_object(name, "none", {MODEL: ts}),
                    lambda name=name: b.snapshot.named(name),
                )
            )
            rec = b.snapshot.named(name)
            assert rec is not None  # seen above
            oid = rec.object_id
            times["deletion"].append(
                _seen(lambda oid=oid: b.remove_object(oid), lambda oid=oid: oid not in a.snapshot.objects)
            )
    finally:
        a.client.drop_collection(a.collections[MODEL])
        a.client.drop_collection(a.objects_collection)
        b.close()
        a.close()
    out: dict = {"poll_seconds": a.poll_seconds}
    for what, pairs in times.items():
        seen, call = np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])
        out[what] = {
            "seen_p50_ms": float(np.median(seen) * 1e3),
            "seen_max_ms": float(seen.max() * 1e3),
            "call_p50_ms": float(np.median(call) * 1e3),
            "runs": len(pairs),
        }
    return out


def _replica_start(store, uri: str, shared: Path, models: dict, queries: np.ndarray, k: int) -> dict:
    """A replica's store started after the registrations (`store`'s, through the other replica): seconds
    from opening it (the store's records, the shared directory's marker, every object's templates) until
    its snapshot answers `queries` exactly as `store`'s does, three times (the median and the slowest)."""
    from index.store.milvus import MilvusStore

    def answers(snap) -> list[list[tuple[int, float, float]]]:
        return [
            [(m.object_id, m.azimuth, round(m.distance, 5)) for m in snap.answers(MODEL, q[None], k)]
            for q in queries
        ]

    want = answers(store.snapshot)
    seconds = []
    for _ in range(3):
        t0 = time.perf_counter()
        replica = MilvusStore(uri, shared, models, prefix=store.prefix, timeout=120)
        try:
            while answers(replica.snapshot) != want:
                if time.perf_counter() - t0 > 300:
                    raise RuntimeError("the new replica never answered as the first one")
                time.sleep(0.05)
            seconds.append(time.perf_counter() - t0)
        finally:
            replica.close()
    return {"objects": len(store.snapshot.objects), "p50_s": float(np.median(seconds)),
            "max_s": float(np.max(seconds)), "runs": len(seconds)}  # fmt: skip


def _seen(change, seen, hang_s: float = 300.0) -> tuple[float, float]:
    """Seconds from the start of `change()` (run on a thread) until `seen()` holds, polled every
    millisecond, and until `change()` returned; `hang_s` only ends a wait that never would."""
    done: list[float] = []
    failed: list[BaseException] = []

    def call() -> None:
        try:
            change()
        except BaseException as e:  # raised again below, on the caller's thread
            failed.append(e)
        done.append(time.perf_counter() - t0)

    t0 = time.perf_counter()
    worker = threading.Thread(target=call)
    worker.start()
    while not seen() and not failed:
        if time.perf_counter() - t0 > hang_s:
            raise RuntimeError(f"the other replica never saw the change ({hang_s:.0f} s)")
        time.sleep(0.001)
    seen_s = time.perf_counter() - t0
    worker.join()
    if failed:
        raise failed[0]
    return seen_s, done[0]


def _faiss_snapshot(sets: list[TemplateSet]) -> FaissSnapshot:
    from benchmarks.stores.build import flat_snapshot

    return flat_snapshot(MODEL, sets)


def _bulk_load(store, sets: list[TemplateSet], batch: int = 50_000) -> None:
    """Objects 1..N live at once: their templates in batches, their records, then Milvus's index built
    over all of it (flush seals the segments; the index is built on sealed ones)."""
    coll = store.collections[MODEL]
    desc = np.concatenate([s.descriptors for s in sets]).astype(np.float32)
    p = np.concatenate([s.poses for s in sets])
    oids = np.repeat(np.arange(1, len(sets) + 1), [len(s.poses) for s in sets])
    for s in tqdm(range(0, len(desc), batch), desc="milvus: bulk insert", unit="batch", disable=None):
        rows = [
            {
                "object_id": int(o),
                "azimuth": float(q[0]),
                "elevation": float(q[1]),
                "inplane": float(q[2]),
                "descriptor": d,
            }  # fmt: skip
            for o, q, d in zip(
                oids[s : s + batch], p[s : s + batch], desc[s : s + batch].tolist(), strict=True
            )
        ]
        store.client.insert(coll, rows, timeout=300)
    now = time.time()
    records = [
        {
            "token": uuid.uuid4().hex,
            "object_id": j + 1,
            "name": f"object-{j + 1}",
            "state": 1,
            "symmetry": "none",
            "faces": 0,
            "created": now,
            "updated": now,
            "templates": json.dumps({coll: len(s.poses)}),
            "extra": "{}",
            "v": [0.0, 0.0],
        }  # fmt: skip
        for j, s in enumerate(sets)
    ]
    for s in range(0, len(records), 5000):
        store.client.insert(store.objects_collection, records[s : s + 5000], timeout=300)
    store.client.flush(coll, timeout=600)
    deadline = time.monotonic() + 1800
    while time.monotonic() < deadline:
        info = store.client.describe_index(coll, "descriptor", timeout=60)
        if int(info.get("pending_index_rows", 1)) == 0 and int(info.get("indexed_rows", 0)) >= len(desc):
            break
        time.sleep(2)
    store.client.refresh_load(coll, timeout=600) if hasattr(store.client, "refresh_load") else None
    store._refresh()


def _registrations(store, ts: TemplateSet, repeats: int) -> dict:
    seconds = []
    for i in range(repeats):
        t0 = time.perf_counter()
        rec: ObjectRecord = store.add_object(f"new-{uuid.uuid4().hex[:6]}-{i}", "none", {MODEL: ts})
        seconds.append(time.perf_counter() - t0)
        store.remove_object(rec.object_id)
    return {
        "p50_ms": float(np.median(seconds) * 1e3),
        "max_ms": float(np.max(seconds) * 1e3),
        "runs": repeats,
    }


def _recall(milvus_snap, exact_snap, queries: np.ndarray, k: int) -> float:
    def keys(snap) -> list[set[tuple[int, float]]]:
        return [{(m.object_id, m.azimuth) for m in row} for row in snap.search(MODEL, queries, k)]

    got, want = keys(milvus_snap), keys(exact_snap)
    return float(np.mean([len(g & w) / max(1, len(w)) for g, w in zip(got, want, strict=True)]))


def _milvus_memory(store) -> dict:
    """What Milvus says of the collection: rows; the vectors' own bytes for scale."""
    stats = store.client.get_collection_stats(store.collections[MODEL], timeout=60)
    return {"rows": int(stats.get("row_count", 0))}


__all__ = ["MilvusConfig", "ModelIndex", "run"]
