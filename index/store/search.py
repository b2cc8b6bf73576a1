"""Searching a store's state: a `Snapshot` is what one search sees from start to end (the objects and, per
model, the templates), whatever the backend; `FaissSnapshot` is the embedded store's, its indexes in
memory. Both answer through the same code: the k nearest templates of each query (`search`) and the k
best distinct (object, viewpoint) answers of a query cut several times (`answers`). A snapshot `within`
some of its objects searches their templates only (a query cut through one window class searches that
class's objects: `index.templates.windows`)."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Protocol, overload

import faiss
import numpy as np

from index.geometry.pose import wrap_degrees
from index.store.answers import distinct
from index.store.records import Match, ObjectRecord, local_key

#: local features of a model's viewpoints, by `index.store.records.local_key`: (F,) float16 each
LocalFeatures = Mapping[tuple[int, float, float], np.ndarray]


class ModelTemplates(Protocol):
    """What every backend tells of one model's templates in a snapshot."""

    @property
    def size(self) -> int: ...

    @property
    def local(self) -> LocalFeatures: ...


@dataclass(frozen=True)
class ModelIndex:
    """One model's FAISS index and, aligned with its ids (ascending), each template's object and pose."""

    index: faiss.Index
    ids: np.ndarray
    object_ids: np.ndarray
    poses: np.ndarray
    #: local features of the viewpoints that have them, by `local_key` (F,) float16
    local: LocalFeatures = field(default_factory=dict)

    @property
    def size(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class Snapshot(ABC):
    """An immutable state of a store: what a search sees from start to end."""

    generation: int
    objects: Mapping[int, ObjectRecord]
    models: Mapping[str, ModelTemplates]

    @abstractmethod
    def knn(self, model: str, queries: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The n nearest templates of each query (Q, D) among this snapshot's objects: squared L2
        distances (Q, n), object ids (Q, n; -1 where fewer were found) and poses (Q, n, 3), nearest first."""

    @abstractmethod
    def within(self, object_ids: frozenset[int]) -> Snapshot:
        """This snapshot seeing only these of its objects: their records, their templates in searches."""

    def size(self, model: str) -> int:
        """How many templates of `model` a search looks through."""
        return self.models[model].size

    def named(self, name: str) -> ObjectRecord | None:
        """The object of this name, if any."""
        return next((r for r in self.objects.values() if r.name == name), None)

    def _match(self, oid: int, pose: np.ndarray, d2: float, inplane: float | None = None) -> Match:
        return Match(
            object_id=int(oid),
            name=self.objects[int(oid)].name,
            azimuth=float(pose[0]),
            elevation=float(pose[1]),
            inplane=float(pose[2]) if inplane is None else inplane,
            distance=float(np.sqrt(max(float(d2), 0.0))),
        )

    def search(self, model: str, queries: np.ndarray, k: int) -> list[list[Match]]:
        """The k nearest templates of each query descriptor (Q, D), nearest first (fewer if the store is small)."""
        size = self.size(model)
        if size == 0 or k <= 0:
            return [[] for _ in range(len(queries))]
        dist, oids, poses = self.knn(model, np.ascontiguousarray(queries, np.float32), min(k, size))
        return [
            [self._match(o, p, d) for o, p, d in zip(orow, prow, drow, strict=True) if o >= 0]
            for drow, orow, prow in zip(dist, oids, poses, strict=True)
        ]

    def answers(
        self,
        model: str,
        queries: np.ndarray,
        k: int,
        offsets: np.ndarray | None = None,
        variants: int = 1,
        most: int = 8192,
        weights: Mapping[int, float] | None = None,
    ) -> Nearest:
        """The k best distinct (object, viewpoint) answers to one query described by Q descriptors (Q, D):
        the query cut Q times, turned by `offsets` (Q,) degrees (`index.features.patches.crop`'s in-plane, undone
        roll; default 0). A template of in-plane θ found for a turn by o says the object is rolled θ + o,
        wrapped to (-180, 180]; the in-plane variants and turns of one viewpoint collapse to their
        nearest (`index.store.answers.distinct`). Each turn searches k * min(`variants`, 4) neighbours
        (`variants`: the templates a viewpoint has), twice as many (up to `most`) while they hold fewer
        than k distinct viewpoints; fewer answers than k only when the store is small. `weights`: an object's
        distances count times its weight in choosing the k among twice as many neighbours (a shape-only
        object's in colour, `Settings.shape_handicap`); the distances returned are the descriptors'."""
        size = self.size(model)
        if size == 0 or k <= 0:
            return Nearest(self.objects, np.zeros(0, int), np.zeros((0, 3)), np.zeros(0))
        q = np.ascontiguousarray(queries, np.float32)
        q = q.reshape(len(q), -1) if q.ndim > 1 else q.reshape(1, -1)
        offsets = np.zeros(len(q)) if offsets is None else np.asarray(offsets, float)
        # k * 4 neighbours held k distinct viewpoints for every validation query with 12 variants (the
        # fewest: 225 distinct in the 800 nearest for k = 200); fewer found: the search goes on with twice
        # as many, so the answers are those of searching everything
        n = min(size, max(k, k * min(variants, 4)) * (2 if weights else 1), most)
        while True:
            dist, ids, allposes = self.knn(model, q, n)
            turn, col = np.nonzero(ids >= 0)
            oid, poses, d = ids[turn, col], allposes[turn, col], dist[turn, col]
            best = distinct((oid, poses[:, 0], poses[:, 1]), _weighed(d, oid, weights), k)
            if len(best) >= k or n >= min(size, most):
                break
            n = min(size, most, 2 * n)
        inplane = np.asarray(wrap_degrees(poses[best, 2].astype(float) + offsets[turn[best]]), float)
        poses = np.column_stack([poses[best, :2].astype(float), inplane])
        return Nearest(self.objects, oid[best], poses, np.sqrt(np.maximum(d[best].astype(float), 0.0)))


def _weighed(d2: np.ndarray, oid: np.ndarray, weights: Mapping[int, float] | None) -> np.ndarray:
    """Squared distances `d2` of objects `oid`, each times its weight squared (`Snapshot.answers`)."""
    if not weights:
        return d2
    ids, at = np.unique(oid, return_inverse=True)
    return d2 * np.array([weights.get(int(o), 1.0) for o in ids])[at] ** 2


class Nearest(Sequence[Match]):
    """`Snapshot.answers` as arrays: object ids (k,), poses (k, 3) (azimuth, elevation and the in-plane
    the query's turn gives), descriptor distances (k,); each a `Match` when read. The re-ranking reads the
    keys and rolls of its 400 candidates from the arrays (`keys`, `rolls`), and only the answers returned
    become `Match` objects: making all of them took 4 ms of a query at 100 objects (cProfile)."""

    def __init__(
        self,
        objects: Mapping[int, ObjectRecord],
        object_ids: np.ndarray,
        poses: np.ndarray,
        distances: np.ndarray,
    ):
        self.objects, self.object_ids, self.poses, self.distances = objects, object_ids, poses, distances

    def __len__(self) -> int:
        return len(self.object_ids)

    @overload
    def __getitem__(self, i: int) -> Match: ...

    @overload
    def __getitem__(self, i: slice) -> list[Match]: ...

    def __getitem__(self, i: int | slice) -> Match | list[Match]:
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        oid, (az, el, ip) = int(self.object_ids[i]), self.poses[i].tolist()
        return Match(oid, self.objects[oid].name, az, el, ip, float(self.distances[i]))

    def keys(self) -> list[tuple[int, float, float]]:
        """Each answer's viewpoint as local features are found by it (`index.store.records.local_key`)."""
        views = zip(self.object_ids.tolist(), self.poses[:, :2].tolist(), strict=True)
        return [local_key(o, a, e) for o, (a, e) in views]

    def rolls(self) -> list[float]:
        """Each answer's in-plane, to 1e-3 degrees (as the re-ranking keys a roll)."""
        return [round(r, 3) for r in self.poses[:, 2].tolist()]


@dataclass(frozen=True)
class FaissSnapshot(Snapshot):
    """The embedded store's state: each model's FAISS index in memory (`ModelIndex`). `only`, in a
    snapshot `within` some objects: per model, the search's selection of their templates and its size."""

    models: Mapping[str, ModelIndex]
    only: Mapping[str, Selection] | None = None

    def size(self, model: str) -> int:
        return self.models[model].size if self.only is None else self.only[model].size

    def within(self, object_ids: frozenset[int]) -> FaissSnapshot:
        # kept per snapshot: every query of a store with several window classes asks for the same ones
        if (hit := self._within.get(object_ids)) is None:
            ids = sorted(object_ids)
            only = {m: Selection.of(mi, ids) for m, mi in self.models.items()}
            objects = {o: self.objects[o] for o in ids if o in self.objects}
            hit = self._within[object_ids] = FaissSnapshot(self.generation, objects, self.models, only)
        return hit

    @cached_property
    def _within(self) -> dict[frozenset[int], FaissSnapshot]:
        return {}

    def knn(self, model: str, queries: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        mi = self.models[model]
        params = None if self.only is None else self.only[model].params()
        dist, ids = mi.index.search(queries.reshape(len(queries), mi.index.d), n, params=params)
        pos = np.searchsorted(mi.ids, np.where(ids >= 0, ids, 0))
        pos = np.minimum(pos, max(mi.size - 1, 0))
        oids = np.where(ids >= 0, mi.object_ids[pos], -1)
        return dist, oids, mi.poses[pos]


@dataclass(frozen=True)
class Selection:
    """Some objects' templates in one model's index: their FAISS selector and how many there are.

    A search takes its own parameters (`params`): FAISS's `IndexIDMap` swaps the selector in the
    parameters it is given for the time of a search, so two threads searching with one parameters
    object crash the process (it did: two places of a frame verified at once against one window class)."""

    selector: faiss.IDSelector
    size: int
    nprobe: int | None = None  # an IVF index's: given parameters replace the index's own

    @classmethod
    def of(cls, mi: ModelIndex, object_ids: list[int]) -> Selection:
        ids = np.ascontiguousarray(mi.ids[np.isin(mi.object_ids, object_ids)], np.int64)
        ivf = faiss.try_extract_index_ivf(mi.index)
        nprobe = None if ivf is None else int(ivf.nprobe)
        return cls(faiss.IDSelectorBatch(ids), len(ids), nprobe)

    def params(self) -> faiss.SearchParameters:
        """New search parameters selecting these templates (the selector, read only, is shared: FAISS
        holds it by a bare pointer, so it lives as long as this selection)."""
        if self.nprobe is None:
            params = faiss.SearchParameters()
        else:
            params = faiss.SearchParametersIVF()
            params.nprobe = self.nprobe
        params.sel = self.selector
        return params
