"""What a Milvus replica searches (`MilvusSnapshot`: the live objects it knew at one poll, each model's
template count and local features), the records' states, and the collections' names."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from index.store.search import LocalFeatures, Snapshot

PENDING, LIVE, DELETED = 0, 1, 2
MAX_ROWS = 16384  # Milvus's largest query result: records are read in one query (docs/scaling.md)


class RawSearch(Protocol):
    """What a snapshot searches through (`index.store.milvus.MilvusStore.search_raw`)."""

    def search_raw(self, model: str, queries: np.ndarray, n: int, expr: str) -> list[list[dict]]: ...


@dataclass(frozen=True)
class MilvusModel:
    """One model's templates in a Milvus snapshot: how many the live objects have, their local features."""

    size: int
    local: LocalFeatures


@dataclass(frozen=True)
class MilvusSnapshot(Snapshot):
    """The live objects a replica knew at one poll; searches go to Milvus, filtered to exactly those."""

    models: Mapping[str, MilvusModel]
    store: RawSearch
    #: the search filter: templates of these objects only (pending and deleted ones are left out)
    expr: str

    def within(self, object_ids: frozenset[int]) -> MilvusSnapshot:
        live = {o: r for o, r in self.objects.items() if o in object_ids}
        models = {
            m: MilvusModel(sum(r.templates.get(m, 0) for r in live.values()), mm.local)
            for m, mm in self.models.items()
        }
        return replace(self, objects=live, models=models, expr=f"object_id in {sorted(live)}")

    def knn(self, model: str, queries: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        hits = self.store.search_raw(model, queries, n, self.expr)
        dist = np.full((len(queries), n), np.inf, np.float32)
        oids = np.full((len(queries), n), -1, np.int64)
        poses = np.zeros((len(queries), n, 3), np.float32)
        for qi, row in enumerate(hits):
            j = 0
            for h in row:
                e = h["entity"]
                # an object that went live after this snapshot was taken is not one of its objects
                if int(e["object_id"]) not in self.objects:
                    continue
                dist[qi, j] = h["distance"]  # Milvus's L2 is squared, as FAISS's
                oids[qi, j] = e["object_id"]
                poses[qi, j] = (e["azimuth"], e["elevation"], e["inplane"])
                j += 1
        return dist, oids, poses


def collection_name(prefix: str, model: str, fingerprint: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]", "_", f"{prefix}_t_{model}_{fingerprint}")


def short(e: BaseException) -> str:
    """One line of a pymilvus or grpc error."""
    text = getattr(e, "message", None) or getattr(e, "details", lambda: None)() or str(e)
    return " ".join(str(text).split())[:300]
