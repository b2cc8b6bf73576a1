"""k-NN latency and memory against the number of templates, exact against IVF, with IVF's recall.

The indexes are built as `index.store.Store` builds them: "flat" is `IndexIDMap2(IndexFlatL2)`, "ivf" is
`IndexIVFFlat` with the store's own `nlist` and `nprobe` (read from its signature, so they stay in
step), used only from 39 x nlist templates on (below that the store stays exact). IVF's quantiser is
trained on a sample (`train_sample`), as k-means on 10^7 points would take longer than the rest.

The descriptors are synthetic and shaped like a store's: objects of 301 templates each, 16 values; an
object's templates scatter around its centre (sigma 0.35 against centres spread with sigma 1), and a
query is a template plus noise (sigma 0.05), a patch seen at a template's pose. Latency is one query
(batch 1), one FAISS thread, as the service searches. Memory is the process's resident size grown by
building the index (the vectors, the id map, IVF's lists)."""

from __future__ import annotations

import gc
import inspect
from collections.abc import Iterator
from dataclasses import dataclass

import faiss
import numpy as np
from tqdm import tqdm

from benchmarks.timing import Timing, live_bytes, measure, return_freed_memory
from index.store import Store, set_threads

_STORE = inspect.signature(Store).parameters
NLIST, NPROBE = int(_STORE["nlist"].default), int(_STORE["nprobe"].default)
TEMPLATES_PER_OBJECT = 301


@dataclass(frozen=True)
class KnnConfig:
    sizes: tuple[int, ...] = (10**4, 10**5, 10**6, 10**7)
    dim: int = 16
    k: int = 5
    queries: int = 200  # timed single queries per index (fewer on the largest, see `_queries_for`)
    recall_queries: int = 300  # exact top-k of these, batched, to score IVF against
    train_sample: int = 100 * NLIST
    search_threads: int = 1  # the service's
    build_threads: int = 2  # building is not timed
    seed: int = 0


CHUNK = 1 << 20


class Synthetic:
    """n descriptors (dim values, float32), objects of 301 templates around their centres, made chunk by
    chunk and the same on every pass, so that a store of 10^7 is never held twice (array and index)."""

    def __init__(self, n: int, dim: int, seed: int):
        self.n, self.dim, self.seed = n, dim, seed
        rng = np.random.default_rng([seed, n])
        self.centres = rng.standard_normal((n // TEMPLATES_PER_OBJECT + 1, dim), dtype=np.float32)

    def chunks(self) -> Iterator[tuple[int, np.ndarray]]:
        """(first row, rows (<= CHUNK, dim)) over the whole set."""
        for lo in range(0, self.n, CHUNK):
            hi = min(self.n, lo + CHUNK)
            noise = np.random.default_rng([self.seed, self.n, lo]).standard_normal(
                (hi - lo, self.dim), np.float32
            )
            yield lo, self.centres[np.arange(lo, hi) // TEMPLATES_PER_OBJECT] + 0.35 * noise

    def rows(self, which: np.ndarray) -> np.ndarray:
        """The rows `which` (in that order)."""
        out = np.zeros((len(which), self.dim), np.float32)
        for lo, chunk in self.chunks():
            inside = (which >= lo) & (which < lo + len(chunk))
            out[inside] = chunk[which[inside] - lo]
        return out


def _queries_for(n: int, cfg: KnnConfig) -> int:
    return max(10, cfg.queries // 10) if n >= 10**7 else cfg.queries


def _build(kind: str, data: Synthetic, cfg: KnnConfig, rng: np.random.Generator) -> tuple[faiss.Index, int]:
    """The index and the bytes the process grew by while building it."""
    sample = (
        data.rows(rng.choice(data.n, min(data.n, cfg.train_sample), replace=False)) if kind == "ivf" else None
    )
    before = live_bytes()
    if sample is not None:
        index: faiss.Index = faiss.IndexIVFFlat(faiss.IndexFlatL2(data.dim), data.dim, NLIST)
        index.train(sample)
        faiss.extract_index_ivf(index).nprobe = NPROBE
    else:
        index = faiss.IndexIDMap2(faiss.IndexFlatL2(data.dim))
    for lo, chunk in data.chunks():
        index.add_with_ids(chunk, np.arange(lo + 1, lo + 1 + len(chunk), dtype=np.int64))
    del chunk, sample
    return index, max(0, live_bytes() - before)


def run(cfg: KnnConfig) -> dict:
    rng = np.random.default_rng(cfg.seed)
    return_freed_memory()
    out: dict = {
        "dim": cfg.dim,
        "k": cfg.k,
        "ivf": {
            "nlist": NLIST,
            "nprobe": NPROBE,
            "min_templates": 39 * NLIST,
            "train_sample": cfg.train_sample,
        },
        "threads": {"search": cfg.search_threads, "build": cfg.build_threads},
        "descriptors": "synthetic: objects of 301 templates, sigma 0.35 around centres of sigma 1; "
        "queries: a template + sigma 0.05",
        "by_size": {},
    }
    for n in tqdm(cfg.sizes, desc="k-NN: store sizes", unit="size", disable=None):
        data = Synthetic(n, cfg.dim, cfg.seed)
        nq = max(_queries_for(n, cfg), min(cfg.recall_queries, n))
        queries = data.rows(rng.choice(n, nq, replace=False))
        queries += 0.05 * rng.standard_normal((nq, cfg.dim), dtype=np.float32)
        row: dict = {"templates": n, "vectors_bytes": n * cfg.dim * 4}
        exact_ids = None
        for kind in ("flat", "ivf"):
            if kind == "ivf" and n < 39 * NLIST:
                row["ivf"] = None  # the store keeps an exact index this small
                continue
            set_threads(cfg.build_threads)
            index, grown = _build(kind, data, cfg, rng)
            set_threads(cfg.search_threads)
            t = _latency(index, queries[: _queries_for(n, cfg)], cfg.k)
            set_threads(cfg.build_threads)
            _, found = index.search(queries[: cfg.recall_queries], cfg.k)
            set_threads(cfg.search_threads)
            row[kind] = t.ms() | {"memory_bytes": grown, "bytes_per_template": grown / n}
            if kind == "flat":
                exact_ids = found
            else:
                row[kind]["recall_at_k"] = _recall(found, exact_ids)
                row[kind]["recall_at_1"] = float(np.mean(found[:, 0] == exact_ids[:, 0]))  # type: ignore[index]
            del index
            gc.collect()
        if row.get("ivf"):
            row["flat_vs_ivf_latency_ratio"] = row["flat"]["median_ms"] / row["ivf"]["median_ms"]
        out["by_size"][str(n)] = row
    return out


def _latency(index: faiss.Index, queries: np.ndarray, k: int) -> Timing:
    """One query at a time, a different one each run."""
    order = iter(range(1 << 40))
    return measure(lambda: index.search(queries[next(order) % len(queries)][None], k), len(queries))


def _recall(found: np.ndarray, exact: np.ndarray | None) -> float:
    """Mean over queries of the share of the exact k nearest that were found."""
    if exact is None:
        return float("nan")
    return float(np.mean([len(set(f) & set(e)) / len(e) for f, e in zip(found, exact, strict=True)]))
