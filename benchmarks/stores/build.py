"""Template stores of many objects for the benchmarks, searched by the service's own code.

`flat_snapshot` builds in one go what `index.store.Store` would hold after registering the objects one by
one with the default index kind (`IndexIDMap2(IndexFlatL2)`), as an `index.store.search.FaissSnapshot`, whose
`search` is the very call a recognition makes. Registering 1,000 objects through `Store.add_object`
instead would rewrite every model's index snapshot file once per object (quadratic in the store size).
`fill_data_dir` and `fill_store` do go through `Store.add_object`, for a data dir the real service (or
`service.state.load_state`) then serves."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import faiss
import numpy as np

from benchmarks.objects import ObjectSet
from index.features.embed import Embedder, store_keys
from index.store import FaissSnapshot, ModelIndex, ObjectRecord, Store, TemplateSet


def flat_snapshot(model: str, sets: list[TemplateSet]) -> FaissSnapshot:
    """Objects 1..N with these templates (one set per object) in one model's exact index."""
    desc = np.ascontiguousarray(np.concatenate([s.descriptors for s in sets]), np.float32)
    poses = np.concatenate([s.poses for s in sets]).astype(np.float32)
    object_ids = np.concatenate([np.full(len(s.poses), j + 1, np.int64) for j, s in enumerate(sets)])
    ids = np.arange(1, len(desc) + 1, dtype=np.int64)
    index = faiss.IndexIDMap2(faiss.IndexFlatL2(desc.shape[1]))
    index.add_with_ids(desc, ids)
    now = time.time()
    objects = {
        j + 1: ObjectRecord(j + 1, f"object-{j + 1}", "none", 0, now, {model: len(s.poses)})
        for j, s in enumerate(sets)
    }
    return FaissSnapshot(1, objects, {model: ModelIndex(index, ids, object_ids, poses)})


def fill_data_dir(
    data_dir: Path,
    embedders: Mapping[str, Embedder],
    objects: ObjectSet,
    n: int,
    progress: Callable[[int], object] | None = None,
) -> None:
    """Registers objects 0..n-1 of `objects` into a new data dir for every model, as the service would
    (one transaction per object); no mesh is kept, so they cannot be re-embedded. `progress` counts
    n x (models + 1) steps: embedding per model, then storing."""
    for e in embedders.values():
        objects.embed_all(e, n, progress)
    sets = {m: [objects.template_set(e, j) for j in range(n)] for m, e in embedders.items()}
    fill_store(data_dir, store_keys(embedders), sets, progress)


def fill_store(
    data_dir: Path,
    models: Mapping[str, tuple[int, str]],
    sets: Mapping[str, Sequence[TemplateSet]],
    progress: Callable[[int], object] | None = None,
) -> None:
    """Adds object j with `sets[model][j]` for every model to the store of `data_dir` (`models`: each
    model's descriptor dim and fingerprint, as `Store` takes them) through `Store.add_object`, one
    transaction per object as a registration; no mesh is kept. `progress` counts objects."""
    n = min(len(s) for s in sets.values())
    store = Store(data_dir, models)
    try:
        for j in range(n):
            store.add_object(
                f"object-{j + 1}", "none", {m: s[j] for m, s in sets.items()}, extra={"benchmark": True}
            )
            if progress:
                progress(1)
    finally:
        store.close()
