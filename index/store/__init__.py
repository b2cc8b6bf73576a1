"""The template store: what the service, `posedesc build-index`, the evaluation and the benchmarks keep
templates in, behind one interface (`TemplateStore`) with two backends, chosen by one setting
(`POSEDESC_STORE`, `open_store`):

- `embedded` (the default): FAISS indexes in memory, SQLite as truth, in one data directory that one
  process owns (`index.store.embedded`; its index snapshot files: `index.store.snapshot_files`).
- a Milvus URI as pymilvus takes it (`http://host:19530`): templates in Milvus, shared by any number of
  service replicas, the meshes and local features in the data directory they share
  (`index.store.milvus`).

Both hand out immutable `Snapshot`s (`index.store.search`): what one search sees from start to end. The records
a store holds and its errors: `index.store.records`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Protocol

import faiss
import numpy as np

from index.store.embedded import EmbeddedStore
from index.store.records import (
    Match,
    NameTaken,
    ObjectRecord,
    StoreError,
    StoreUnavailable,
    TemplateSet,
    local_key,
)
from index.store.search import FaissSnapshot, ModelIndex, Snapshot
from index.store.snapshot_files import AUTO_IVF_MIN, INDEX_KINDS
from index.store.sqlite_file import SCHEMA, changed_models, check_store

__all__ = [
    "INDEX_KINDS",
    "SCHEMA",
    "EMBEDDED",
    "EmbeddedStore",
    "FaissSnapshot",
    "Match",
    "ModelIndex",
    "NameTaken",
    "ObjectRecord",
    "Snapshot",
    "Store",
    "StoreError",
    "StoreUnavailable",
    "TemplateSet",
    "TemplateStore",
    "changed_models",
    "check_location",
    "check_store",
    "local_key",
    "open_store",
    "set_threads",
]

EMBEDDED = "embedded"

#: the embedded store under its historical name
Store = EmbeddedStore


class TemplateStore(Protocol):
    """What the service and the tools ask of a store, whatever the backend. `models` (at open) maps a model
    name to (descriptor dim, fingerprint of the model file); a model whose fingerprint changed has no
    templates until they are made again (`missing`, `index.templates.register.reembed`)."""

    @property
    def dims(self) -> Mapping[str, int]: ...

    @property
    def snapshot(self) -> Snapshot: ...

    def search(self, model: str, queries: np.ndarray, k: int) -> list[list[Match]]: ...

    def missing(self) -> dict[str, list[int]]: ...

    def mesh_bytes(self, object_id: int) -> bytes | None: ...

    def get_meta(self, key: str) -> str | None: ...

    def set_meta(self, key: str, value: str) -> None: ...

    def has_held_objects(self) -> bool: ...

    def add_object(
        self,
        name: str,
        symmetry: str,
        templates: Mapping[str, TemplateSet],
        faces: int = 0,
        mesh: bytes | None = None,
        extra: Mapping[str, object] | None = None,
    ) -> ObjectRecord: ...

    def add_templates(self, object_id: int, model: str, ts: TemplateSet) -> None: ...

    def remove_object(self, object_id: int) -> bool: ...

    def problem(self) -> str | None:
        """Why the store cannot serve now (its server unreachable), or None."""
        ...

    def close(self) -> None: ...


def open_store(
    location: str,
    data_dir: str | Path,
    models: Mapping[str, tuple[int, str]],
    kind: str = "auto",
    sweep_seconds: float = 600.0,
    prefix: str = "posedesc",
    ivf_min: int = AUTO_IVF_MIN,
) -> TemplateStore:
    """`location`: "embedded", or a Milvus URI (`http://host:19530`; `data_dir` then is the directory
    the replicas share for meshes, local features and job states). `kind` and `ivf_min` (the embedded
    store's index: `index.store.snapshot_files.ivf_from`)."""
    if location == EMBEDDED:
        return EmbeddedStore(data_dir, models, kind=kind, ivf_min=ivf_min)
    if "://" not in location:
        raise StoreError(
            f"POSEDESC_STORE={location!r}: use 'embedded' or a Milvus URI such as http://host:19530"
        )
    from index.store.milvus import MilvusStore  # pymilvus only where Milvus is used

    return MilvusStore(location, data_dir, models, prefix=prefix, sweep_seconds=sweep_seconds)


def check_location(location: str, timeout: float = 10.0) -> None:
    """Raises StoreError (one line) when `location` is neither "embedded" nor a Milvus that answers."""
    if location == EMBEDDED:
        return
    if "://" not in location:
        raise StoreError(
            f"POSEDESC_STORE={location!r}: use 'embedded' or a Milvus URI such as http://host:19530"
        )
    from pymilvus import MilvusClient

    try:
        client = MilvusClient(location, timeout=timeout)
        client.list_collections(timeout=timeout)
        client.close()
    except Exception as e:
        raise StoreError(
            f"the template store (Milvus at {location}) does not answer: {str(e).splitlines()[0][:200]}"
        ) from None


def set_threads(n: int) -> None:
    """FAISS's OpenMP threads. The service runs on 2 cores shared by the web workers, onnxruntime and
    the render thread; a 16-d flat search over a few 10k templates takes well under a millisecond, so
    OpenMP's spinning workers would only steal cores from concurrent requests: default 1."""
    faiss.omp_set_num_threads(max(1, int(n)))
