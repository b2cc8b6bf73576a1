"""How the embedded store's FAISS indexes are made from SQLite: each model's loaded from its snapshot file of the
store's generation or built from the rows, models holding the same templates sharing one index (tagged
`same_as`), and the snapshot files saved."""

from __future__ import annotations

import json
import logging
import sqlite3
from collections.abc import Mapping
from pathlib import Path

import faiss
import numpy as np

from index.store.local_files import LocalFiles
from index.store.records import ObjectRecord
from index.store.search import FaissSnapshot, ModelIndex
from index.store.snapshot_files import (
    build_index,
    paths,
    read_snapshot,
    read_tag,
    save_snapshot,
    tune,
    write_atomic,
)

log = logging.getLogger("index.store")


class ModelIndexes:
    """The FAISS indexes part of `EmbeddedStore` (its attributes declared here, set there)."""

    _db: sqlite3.Connection
    _files: LocalFiles
    _tags: dict[str, dict]
    dims: dict[str, int]
    dir: Path
    ivf_min: int
    kind: str
    nlist: int
    nprobe: int

    def _load(self) -> FaissSnapshot:
        db = self._db
        generation = int(db.execute("SELECT value FROM meta WHERE key = 'generation'").fetchone()[0])
        counts: dict[int, dict[str, int]] = {}
        for oid, m, n in db.execute(
            "SELECT object_id, model, COUNT(*) FROM templates GROUP BY object_id, model"
        ):
            if m in self.dims:  # templates of a model not loaded now stay in SQLite, unseen
                counts.setdefault(oid, {})[m] = n
        objects = {
            oid: ObjectRecord(oid, name, sym, faces, created, counts.get(oid, {}), json.loads(extra))
            for oid, name, sym, faces, created, extra in db.execute(
                "SELECT id, name, symmetry, faces, created, extra FROM objects"
            )
        }
        self._files.sweep(set(objects))
        models: dict[str, ModelIndex] = {}
        for m in self.dims:
            tag = read_tag(self.dir, m) or {}
            src = tag.get("same_as")
            if tag.get("generation") == generation and src in models and self._rows_match(m, models[src]):
                models[m], self._tags[m] = models[src], tag
            else:
                models[m] = self._load_model(m, generation)
        self._share_twins(models, generation)
        return FaissSnapshot(generation, objects, models)

    def _rows_match(self, model: str, mi: ModelIndex) -> bool:
        """Whether `model`'s templates in SQLite are `mi`'s, pose for pose and object for object, with as
        many local features (what a `same_as` tag of the same generation promises)."""
        rows = self._db.execute(
            "SELECT object_id, azimuth, elevation, inplane, local IS NOT NULL FROM templates "
            "WHERE model = ? ORDER BY id",
            (model,),
        ).fetchall()
        meta = np.array(rows, dtype=float).reshape(-1, 5)
        return (
            len(meta) == mi.size
            and np.array_equal(meta[:, 0].astype(np.int64), mi.object_ids)
            and np.array_equal(meta[:, 1:4].astype(np.float32), mi.poses)
            and int(meta[:, 4].sum()) == len(mi.local)
        )

    def _share_twins(self, models: dict[str, ModelIndex], generation: int) -> None:
        """Models holding the same templates as an earlier one (a store from before sharing, an empty one)
        made to share its index, and tagged so (`same_as`), so that the next start need not compare."""
        names = list(models)
        for i, m in enumerate(names):
            for src in names[:i]:
                if twin_of(models, m) is None and self._same(src, models[src], m, models[m]):
                    models[m] = models[src]
                    try:
                        self._save_index(m, models[m], generation, src)
                    except OSError as e:  # as any snapshot: only a warning, compared again at the next start
                        log.warning("could not tag %s as sharing %s's index: %s", m, src, e)
                    break

    def _same(self, a: str, ia: ModelIndex, b: str, ib: ModelIndex) -> bool:
        """Whether models `a` and `b` hold the same templates: objects and poses in the same order, local
        features, and descriptors (SQLite's, compared row by row: any index kind, little memory)."""
        if self.dims[a] != self.dims[b] or ia.size != ib.size or ia.local.keys() != ib.local.keys():
            return False
        if not (np.array_equal(ia.object_ids, ib.object_ids) and np.array_equal(ia.poses, ib.poses)):
            return False
        for k, f in ia.local.items():
            g = ib.local[k]
            if f.__array_interface__["data"][0] != g.__array_interface__["data"][0] and not np.array_equal(
                f, g
            ):
                return False
        query = "SELECT descriptor FROM templates WHERE model = ? ORDER BY id"
        rows_a, rows_b = self._db.execute(query, (a,)), self._db.execute(query, (b,))
        return all(x == y for (x,), (y,) in zip(rows_a, rows_b, strict=True))

    def _own(self, model: str) -> ModelIndex:
        """`model`'s index from SQLite alone (this connection: an open transaction's rows too)."""
        return self._load_model(model, None)

    def _load_model(self, model: str, generation: int | None) -> ModelIndex:
        """`model`'s index: its snapshot of `generation` when it has one, else built from SQLite and saved
        (not saved for None: in a write, `_swap` saves it)."""
        rows = self._db.execute(
            "SELECT id, object_id, azimuth, elevation, inplane FROM templates WHERE model = ? ORDER BY id",
            (model,),
        ).fetchall()
        meta = np.array(rows, dtype=float).reshape(-1, 5)
        ids, object_ids = meta[:, 0].astype(np.int64), meta[:, 1].astype(np.int64)
        poses = meta[:, 2:].astype(np.float32)
        local = self._files.load(self._db, model)
        index = None if generation is None else self._read_snapshot(model, generation, len(ids))
        if index is None:
            index = self._build(model, ids)
            if generation is not None:
                self._save_loaded(model, ModelIndex(index, ids, object_ids, poses), generation)
        return ModelIndex(index, ids, object_ids, poses, local)

    def _save_loaded(self, model: str, mi: ModelIndex, generation: int) -> None:
        try:
            self._save_index(model, mi, generation)
        except OSError as e:  # a full disk: SQLite is intact and the index is built, so serve on
            log.warning(
                "could not save the %s index snapshot to %s (%s): serving from SQLite; it is rebuilt "
                "at each start until it can be saved",
                model,
                self.dir,
                e,
            )
            self._paths(model)[1].unlink(missing_ok=True)  # as in `_swap`: no tag for a file it lacks

    def _paths(self, model: str) -> tuple[Path, Path]:
        return paths(self.dir, model)

    def _read_snapshot(self, model: str, generation: int, ntotal: int) -> faiss.Index | None:
        found = read_snapshot(self.dir, model, generation, ntotal, self.dims[model], self.kind)
        if found is None:
            return None
        index, tag = found
        tune(index, self.nprobe)
        self._tags[model] = tag
        return index

    def _build(self, model: str, ids: np.ndarray) -> faiss.Index:
        desc = np.zeros((len(ids), self.dims[model]), np.float32)
        rows = self._db.execute("SELECT descriptor FROM templates WHERE model = ? ORDER BY id", (model,))
        for i, (blob,) in enumerate(rows):
            desc[i] = np.frombuffer(blob, np.float32)
        return build_index(desc, ids, self.kind, self.nlist, self.nprobe, self.ivf_min)

    def _save_index(self, model: str, mi: ModelIndex, generation: int, same_as: str | None = None) -> None:
        """Its snapshot file and tag; for a model sharing `same_as`'s index, a tag saying so and no file."""
        if same_as is None:
            self._tags[model] = save_snapshot(self.dir, model, mi.index, generation, self.kind)
            return
        path, tag_path = self._paths(model)
        tag = {
            "generation": generation,
            "ntotal": int(mi.index.ntotal),
            "kind": self.kind,
            "same_as": same_as,
        }
        write_atomic(tag_path, json.dumps(tag).encode())
        path.unlink(missing_ok=True)
        self._tags[model] = tag


def twin_of(models: Mapping[str, ModelIndex], model: str) -> str | None:
    """The earlier model whose index `model` shares, if any."""
    for m, mi in models.items():
        if m == model:
            return None
        if mi is models[model]:
            return m
    return None
