"""The template store: descriptors of every object's templates, one FAISS index per model, SQLite as truth.

Layout of a data directory:
- `store.sqlite`: objects (name, symmetry, the mesh as GLB so templates can be made again), templates
  (object, model, azimuth, elevation, in-plane, the descriptor itself), the models' fingerprints and a
  `generation` counter bumped by every write. One SQLite transaction per write, so after a crash an
  object is wholly present or wholly absent, for every model at once.
- `<model>.faiss` + `<model>.faiss.json`: a snapshot of that model's index, tagged with the generation
  and the file's sha256. On open a snapshot is used only when both match SQLite; otherwise (missing,
  stale, corrupt) the index is rebuilt from SQLite's descriptors. It can never be silently wrong.
  A damaged `store.sqlite` (SQLite's own `quick_check` fails) is refused with a one-line `StoreError`.

A full disk: a write that SQLite cannot commit is rolled back and raises `OSError(ENOSPC)`; the store keeps
its previous state. A snapshot that cannot be written after a commit is only a warning (its tag is
removed, so it is rebuilt at the next start); so is one rebuilt on open that cannot be saved.

Readers never see a half-added object: the live state is an immutable `Snapshot` (indexes + metadata).
A write builds the next one on copies (copy-on-write) and swaps the reference under a lock; a search
runs lock-free on whichever snapshot it picked up. Writers are serialised.

Index kinds: "flat" (default) is exact, `IndexIDMap2(IndexFlatL2)`; "ivf" is `IndexIVFFlat` for large
collections, trained when the index is built from SQLite and exact (flat) until there are enough
templates to train it (39 per list). HNSW is not offered: it cannot remove ids.
"""

from __future__ import annotations

import errno
import hashlib
import json
import logging
import os
import sqlite3
import threading
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import faiss
import numpy as np

from index.answers import distinct
from index.pose import wrap_degrees

log = logging.getLogger(__name__)

INDEX_KINDS = ("flat", "ivf")

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS models (name TEXT PRIMARY KEY, fingerprint TEXT NOT NULL, dim INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS objects (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    name TEXT NOT NULL,
    symmetry TEXT NOT NULL,
    faces INTEGER NOT NULL,
    created REAL NOT NULL,
    extra TEXT NOT NULL,
    mesh BLOB
);
CREATE TABLE IF NOT EXISTS templates (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    object_id INTEGER NOT NULL REFERENCES objects(id) ON DELETE CASCADE,
    model TEXT NOT NULL,
    azimuth REAL NOT NULL,
    elevation REAL NOT NULL,
    inplane REAL NOT NULL,
    descriptor BLOB NOT NULL,
    local BLOB
);
CREATE INDEX IF NOT EXISTS templates_model ON templates(model, object_id);
INSERT OR IGNORE INTO meta VALUES ('generation', '0');
"""


def set_threads(n: int) -> None:
    """FAISS's OpenMP threads. The service runs on 2 cores shared by the web workers, onnxruntime and
    the render thread; a 16-d flat search over a few 10k templates takes well under a millisecond, so
    OpenMP's spinning workers would only steal cores from concurrent requests: default 1."""
    faiss.omp_set_num_threads(max(1, int(n)))


@dataclass(frozen=True)
class ObjectRecord:
    """One registered object. `templates` counts its templates per model."""

    object_id: int
    name: str
    symmetry: str
    faces: int
    created: float
    templates: Mapping[str, int]
    extra: Mapping[str, object] = field(default_factory=dict)


@dataclass(frozen=True)
class Match:
    """A template found for a query: its object, its pose (degrees) and the descriptor distance (L2)."""

    object_id: int
    name: str
    azimuth: float
    elevation: float
    inplane: float
    distance: float


@dataclass(frozen=True)
class TemplateSet:
    """What one model adds for an object. poses: (N, 3) azimuth, elevation, in-plane; descriptors: (N, D).
    A model with local features (`index.embed.LOCAL_NAME`) also gives them for some templates (its
    upright ones): `local_rows` (L,) indices into poses, `local` (L, F) float16."""

    poses: np.ndarray
    descriptors: np.ndarray
    local_rows: np.ndarray | None = None
    local: np.ndarray | None = None


def local_key(object_id: int, azimuth: float, elevation: float) -> tuple[int, float, float]:
    """How a viewpoint's local features are found: object and viewpoint, to 1e-3 degrees."""
    return int(object_id), round(float(azimuth), 3), round(float(elevation), 3)


@dataclass(frozen=True)
class ModelIndex:
    """One model's index and, aligned with its ids (ascending), each template's object and pose."""

    index: faiss.Index
    ids: np.ndarray
    object_ids: np.ndarray
    poses: np.ndarray
    #: local features of the viewpoints that have them, by `local_key` (F,) float16
    local: Mapping[tuple[int, float, float], np.ndarray] = field(default_factory=dict)

    @property
    def size(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class Snapshot:
    """An immutable state of the store: what a search sees from start to end."""

    generation: int
    objects: Mapping[int, ObjectRecord]
    models: Mapping[str, ModelIndex]

    def named(self, name: str) -> ObjectRecord | None:
        """The object of this name, if any."""
        return next((r for r in self.objects.values() if r.name == name), None)

    def search(self, model: str, queries: np.ndarray, k: int) -> list[list[Match]]:
        """The k nearest templates of each query descriptor (Q, D), nearest first (fewer if the store is small)."""
        mi = self.models[model]
        if mi.size == 0:
            return [[] for _ in range(len(queries))]
        dist, ids = mi.index.search(np.ascontiguousarray(queries, np.float32), min(k, mi.size))
        out = []
        for drow, irow in zip(dist, ids, strict=True):
            keep = irow >= 0
            pos = np.searchsorted(mi.ids, irow[keep])
            out.append(
                [
                    Match(
                        object_id=int(mi.object_ids[p]),
                        name=self.objects[int(mi.object_ids[p])].name,
                        azimuth=float(mi.poses[p, 0]),
                        elevation=float(mi.poses[p, 1]),
                        inplane=float(mi.poses[p, 2]),
                        distance=float(np.sqrt(max(d, 0.0))),
                    )
                    for p, d in zip(pos, drow[keep], strict=True)
                ]
            )
        return out

    def answers(
        self,
        model: str,
        queries: np.ndarray,
        k: int,
        offsets: np.ndarray | None = None,
        variants: int = 1,
        most: int = 8192,
    ) -> list[Match]:
        """The k best distinct (object, viewpoint) answers to one query described by Q descriptors (Q, D):
        the query cut Q times, turned by `offsets` (Q,) degrees (`index.patches.crop`'s in-plane, undone
        roll; default 0). A template of in-plane θ found for a turn by o says the object is rolled θ + o,
        wrapped to (-180, 180]; the in-plane variants and turns of one viewpoint collapse to their
        nearest (`index.answers.distinct`). Each turn searches k * `variants` neighbours (the templates
        a viewpoint has), which holds k distinct viewpoints, more (up to `most`) if not; fewer answers
        than k only when the store is small."""
        mi = self.models[model]
        if mi.size == 0 or k <= 0:
            return []
        q = np.ascontiguousarray(queries, np.float32).reshape(-1, mi.index.d)
        offsets = np.zeros(len(q)) if offsets is None else np.asarray(offsets, float)
        n = min(mi.size, max(k, k * variants), most)
        while True:
            dist, ids = mi.index.search(q, n)
            turn, col = np.nonzero(ids >= 0)
            pos = np.searchsorted(mi.ids, ids[turn, col])
            oid, poses, d = mi.object_ids[pos], mi.poses[pos], dist[turn, col]
            best = distinct((oid, poses[:, 0], poses[:, 1]), d, k)
            if len(best) >= k or n >= min(mi.size, most):
                break
            n = min(mi.size, most, 2 * n)
        return [
            Match(
                object_id=int(oid[b]),
                name=self.objects[int(oid[b])].name,
                azimuth=float(poses[b, 0]),
                elevation=float(poses[b, 1]),
                inplane=float(wrap_degrees(float(poses[b, 2]) + offsets[turn[b]])),
                distance=float(np.sqrt(max(float(d[b]), 0.0))),
            )
            for b in best
        ]


class StoreError(RuntimeError):
    """The data directory cannot be used (a one-line reason)."""


class NameTaken(ValueError):
    """An object of this name is stored already; `object_id` is its id."""

    def __init__(self, name: str, object_id: int):
        super().__init__(f"an object named {name!r} exists already (object_id {object_id})")
        self.name, self.object_id = name, object_id


def check_store(data_dir: str | Path) -> None:
    """Raises StoreError (one line) when `data_dir/store.sqlite` exists and SQLite finds it damaged;
    `posedesc serve` calls it before starting, so a damaged store stops it with a message, not a traceback."""
    path = Path(data_dir) / "store.sqlite"
    if not path.is_file():
        return
    try:
        db = sqlite3.connect(path)
    except sqlite3.Error as e:
        raise StoreError(f"{path} is not a usable store: {e}") from None
    try:
        _check(db, path)
    finally:
        db.close()


def _check(db: sqlite3.Connection, path: Path) -> None:
    try:
        problems = [row[0] for row in db.execute("PRAGMA quick_check(3)")]
    except sqlite3.DatabaseError as e:
        raise StoreError(f"{path} is not a usable store: {e}") from None
    if problems != ["ok"]:
        # a problem may span lines ("*** in database main ***\nPage 8: ..."): the first real one
        lines = [ln for p in problems for ln in p.splitlines() if ln.strip() and not ln.startswith("***")]
        raise StoreError(
            f"{path} is damaged ({(lines or problems)[0]}); restore it from a backup, or move it away "
            "to start empty"
        )


def _disk_full(e: BaseException) -> bool:
    return isinstance(e, sqlite3.Error) and getattr(e, "sqlite_errorcode", None) == sqlite3.SQLITE_FULL


class Store:
    """Templates of all objects for a fixed set of models, persisted in `data_dir`.

    `models` maps a model name to (descriptor dim, fingerprint of the model file). A model whose
    fingerprint changed since the last run has its templates dropped: `missing()` then lists the
    objects to embed again (see `register.reembed`)."""

    def __init__(
        self,
        data_dir: str | Path,
        models: Mapping[str, tuple[int, str]],
        kind: str = "flat",
        nlist: int = 256,
        nprobe: int = 16,
    ):
        if kind not in INDEX_KINDS:
            raise StoreError(f"unknown index kind {kind!r}; use one of {INDEX_KINDS}")
        if not models:
            raise StoreError("a store needs at least one model")
        self.dir = Path(data_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.dims = {m: int(d) for m, (d, _) in models.items()}
        self.kind, self.nlist, self.nprobe = kind, nlist, nprobe
        self._write = threading.Lock()
        self._tags: dict[str, dict] = {}  # the snapshot files' tags, as last written
        path = self.dir / "store.sqlite"
        try:
            self._db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")  # a committed registration survives a power cut
            self._db.execute("PRAGMA foreign_keys=ON")
            _check(self._db, path)
            self._db.executescript(SCHEMA)
            columns = {row[1] for row in self._db.execute("PRAGMA table_info(templates)")}
            if "local" not in columns:  # a store made before local features existed
                self._db.execute("ALTER TABLE templates ADD COLUMN local BLOB")
            self._forget_changed_models(models)
            self._snap = self._load()
        except sqlite3.DatabaseError as e:  # damage quick_check cannot see: a bad row, a bad descriptor
            raise StoreError(f"{path} is not a usable store: {e}") from None
        except StoreError:
            self._db.close()
            raise

    # -- reading -----------------------------------------------------------------------------------

    @property
    def snapshot(self) -> Snapshot:
        """The current state; hold on to it for a consistent view across several calls."""
        return self._snap

    def search(self, model: str, queries: np.ndarray, k: int) -> list[list[Match]]:
        return self._snap.search(model, queries, k)

    def missing(self) -> dict[str, list[int]]:
        """Per model, the objects that have no templates for it (new or changed model, interrupted run)."""
        snap = self._snap
        return {
            m: [oid for oid, rec in snap.objects.items() if rec.templates.get(m, 0) == 0] for m in self.dims
        }

    def mesh_bytes(self, object_id: int) -> bytes | None:
        """The object's mesh as GLB, as registered (mm)."""
        with self._write:
            row = self._db.execute("SELECT mesh FROM objects WHERE id = ?", (object_id,)).fetchone()
        return None if row is None else row[0]

    def get_meta(self, key: str) -> str | None:
        with self._write:
            row = self._db.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else row[0]

    def has_held_objects(self) -> bool:
        """Whether an object was ever added here, even if all were removed since: the objects table's
        AUTOINCREMENT counter (`sqlite_sequence`) only grows, and only with a committed insert."""
        with self._write:
            row = self._db.execute("SELECT seq FROM sqlite_sequence WHERE name = 'objects'").fetchone()
        return row is not None and int(row[0]) > 0

    def set_meta(self, key: str, value: str) -> None:
        with self._write, self._transaction() as cur:
            cur.execute("INSERT OR REPLACE INTO meta VALUES (?, ?)", (key, value))

    # -- writing -----------------------------------------------------------------------------------

    def add_object(
        self,
        name: str,
        symmetry: str,
        templates: Mapping[str, TemplateSet],
        faces: int = 0,
        mesh: bytes | None = None,
        extra: Mapping[str, object] | None = None,
    ) -> ObjectRecord:
        """Adds an object with its templates for every model in one transaction; returns its record.
        Raises NameTaken when an object of that name is stored already (checked in the transaction, so
        two registrations of one name cannot both pass)."""
        for m, ts in templates.items():
            self._check_set(m, ts)
        with self._write:
            with self._transaction() as cur:
                row = cur.execute("SELECT id FROM objects WHERE name = ? LIMIT 1", (name,)).fetchone()
                if row is not None:
                    raise NameTaken(name, int(row[0]))
                created = time.time()
                cur.execute(
                    "INSERT INTO objects (name, symmetry, faces, created, extra, mesh) VALUES (?, ?, ?, ?, ?, ?)",
                    (name, symmetry, int(faces), created, json.dumps(dict(extra or {})), mesh),
                )
                oid = int(cur.lastrowid)  # type: ignore[arg-type]
                new_ids = {m: self._insert_templates(cur, oid, m, ts) for m, ts in templates.items()}
                rec = ObjectRecord(
                    oid,
                    name,
                    symmetry,
                    int(faces),
                    created,
                    {m: len(ids) for m, ids in new_ids.items()},
                    extra or {},
                )
                snap = self._next(
                    cur, add={m: (oid, ids, templates[m]) for m, ids in new_ids.items()}, put=rec
                )
            self._swap(snap)
        return rec

    def add_templates(self, object_id: int, model: str, ts: TemplateSet) -> None:
        """Adds one model's templates to an existing object (re-embedding after a model changed)."""
        self._check_set(model, ts)
        with self._write:
            old = self._snap.objects.get(object_id)
            if old is None:
                raise KeyError(object_id)
            with self._transaction() as cur:
                ids = self._insert_templates(cur, object_id, model, ts)
                counts = {**old.templates, model: old.templates.get(model, 0) + len(ids)}
                rec = replace(old, templates=counts)
                snap = self._next(cur, add={model: (object_id, ids, ts)}, put=rec)
            self._swap(snap)

    def remove_object(self, object_id: int) -> bool:
        """Removes an object and all its templates; False when there is no such object."""
        with self._write:
            if object_id not in self._snap.objects:
                return False
            with self._transaction() as cur:
                cur.execute("DELETE FROM templates WHERE object_id = ?", (object_id,))
                cur.execute("DELETE FROM objects WHERE id = ?", (object_id,))
                snap = self._next(cur, remove=object_id)
            self._swap(snap)
        return True

    def close(self) -> None:
        with self._write:
            self._db.close()

    # -- internals ---------------------------------------------------------------------------------

    @contextmanager
    def _transaction(self) -> Iterator[sqlite3.Cursor]:
        """One SQLite transaction (the caller holds the write lock): committed, or rolled back and
        re-raised; SQLite's "database or disk is full" comes out as OSError(ENOSPC)."""
        cur = self._db.cursor()
        try:
            cur.execute("BEGIN IMMEDIATE")
            yield cur
            cur.execute("COMMIT")
        except BaseException as e:
            # SQLite may have rolled back already (it does on some SQLITE_FULL errors): a second
            # ROLLBACK would fail and hide the real error.
            if self._db.in_transaction:
                try:
                    self._db.execute("ROLLBACK")
                except sqlite3.Error as rollback:
                    log.error("rollback failed after %s: %s", e, rollback)
            if _disk_full(e):
                raise OSError(errno.ENOSPC, f"disk full: could not write {self.dir / 'store.sqlite'}") from e
            raise

    def _check_set(self, model: str, ts: TemplateSet) -> None:
        if model not in self.dims:
            raise KeyError(f"unknown model {model!r}")
        d = np.asarray(ts.descriptors)
        if d.ndim != 2 or d.shape[1] != self.dims[model] or len(d) != len(ts.poses) or len(d) == 0:
            raise ValueError(
                f"{model}: expected (N, {self.dims[model]}) descriptors and N poses, "
                f"got {d.shape} and {np.shape(ts.poses)}"
            )
        if not np.all(np.isfinite(d)):
            raise ValueError(f"{model}: descriptors contain NaN or infinity")

    def _insert_templates(self, cur: sqlite3.Cursor, oid: int, model: str, ts: TemplateSet) -> np.ndarray:
        desc = np.ascontiguousarray(ts.descriptors, np.float32)
        poses = np.asarray(ts.poses, float)
        local: list[bytes | None] = [None] * len(desc)
        if ts.local_rows is not None and ts.local is not None:
            for r, f in zip(ts.local_rows, np.asarray(ts.local, np.float16), strict=True):
                local[int(r)] = f.tobytes()
        first = cur.execute("SELECT COALESCE(MAX(id), 0) + 1 FROM templates").fetchone()[0]
        ids = np.arange(first, first + len(desc), dtype=np.int64)
        cur.executemany(
            "INSERT INTO templates (id, object_id, model, azimuth, elevation, inplane, descriptor, local) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
            (
                (int(i), oid, model, float(p[0]), float(p[1]), float(p[2]), d.tobytes(), f)
                for i, p, d, f in zip(ids, poses, desc, local, strict=True)
            ),
        )
        return ids

    def _next(
        self,
        cur: sqlite3.Cursor,
        add: Mapping[str, tuple[int, np.ndarray, TemplateSet]] | None = None,
        remove: int | None = None,
        put: ObjectRecord | None = None,
    ) -> Snapshot:
        """The snapshot after this write (copies of the changed indexes), with the generation bumped."""
        cur.execute("UPDATE meta SET value = CAST(value AS INTEGER) + 1 WHERE key = 'generation'")
        old = self._snap
        objects = dict(old.objects)
        models = dict(old.models)
        if remove is not None:
            del objects[remove]
            for m, mi in old.models.items():
                gone = mi.object_ids == remove
                if gone.any():
                    index = faiss.clone_index(mi.index)
                    index.remove_ids(mi.ids[gone])
                    local = {k: v for k, v in mi.local.items() if k[0] != remove}
                    models[m] = ModelIndex(index, mi.ids[~gone], mi.object_ids[~gone], mi.poses[~gone], local)
        for m, (oid, ids, ts) in (add or {}).items():
            mi = old.models[m]
            index = faiss.clone_index(mi.index)
            index.add_with_ids(np.ascontiguousarray(ts.descriptors, np.float32), ids)
            local = dict(mi.local)
            if ts.local_rows is not None and ts.local is not None:
                for r, f in zip(ts.local_rows, np.asarray(ts.local, np.float16), strict=True):
                    p = ts.poses[int(r)]
                    local[local_key(oid, p[0], p[1])] = f
            models[m] = ModelIndex(
                index,
                np.concatenate([mi.ids, ids]),  # new ids are larger than all old ones: still ascending
                np.concatenate([mi.object_ids, np.full(len(ids), oid, np.int64)]),
                np.concatenate([mi.poses, np.asarray(ts.poses, np.float32)]),
                local,
            )
        if put is not None:
            objects[put.object_id] = put
        return Snapshot(old.generation + 1, objects, models)

    def _swap(self, snap: Snapshot) -> None:
        old = self._snap
        self._snap = snap  # one reference assignment: readers get the old or the new state, never a mix
        for m, mi in snap.models.items():
            try:
                if old.models.get(m) is not mi:
                    self._save_index(m, mi, snap.generation)
                elif m in self._tags:  # unchanged index: only its tag moves to the new generation
                    tag = {**self._tags[m], "generation": snap.generation}
                    _write_atomic(self._paths(m)[1], json.dumps(tag).encode())
                    self._tags[m] = tag
            except OSError as e:  # the write is committed; a stale snapshot is rebuilt at the next start
                log.warning("could not write the %s index snapshot to %s: %s", m, self.dir, e)
                # Forget the tag and remove its file: a later write must not re-tag a file that lacks
                # this write as current (ntotal would catch most such files, not all).
                self._tags.pop(m, None)
                self._paths(m)[1].unlink(missing_ok=True)

    def _forget_changed_models(self, models: Mapping[str, tuple[int, str]]) -> None:
        known = {n: (f, d) for n, f, d in self._db.execute("SELECT name, fingerprint, dim FROM models")}
        for name, (dim, fingerprint) in models.items():
            if known.get(name) == (fingerprint, dim):
                continue
            if name in known:
                log.warning("model %s changed since its templates were made: they will be made again", name)
            with self._db:
                self._db.execute("BEGIN IMMEDIATE")
                self._db.execute("DELETE FROM templates WHERE model = ?", (name,))
                self._db.execute("INSERT OR REPLACE INTO models VALUES (?, ?, ?)", (name, fingerprint, dim))
                self._db.execute(
                    "UPDATE meta SET value = CAST(value AS INTEGER) + 1 WHERE key = 'generation'"
                )

    def _load(self) -> Snapshot:
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
        models = {m: self._load_model(m, generation) for m in self.dims}
        return Snapshot(generation, objects, models)

    def _load_model(self, model: str, generation: int) -> ModelIndex:
        rows = self._db.execute(
            "SELECT id, object_id, azimuth, elevation, inplane FROM templates WHERE model = ? ORDER BY id",
            (model,),
        ).fetchall()
        meta = np.array(rows, dtype=float).reshape(-1, 5)
        ids, object_ids = meta[:, 0].astype(np.int64), meta[:, 1].astype(np.int64)
        poses = meta[:, 2:].astype(np.float32)
        local = {
            local_key(oid, az, el): np.frombuffer(blob, np.float16)
            for oid, az, el, blob in self._db.execute(
                "SELECT object_id, azimuth, elevation, local FROM templates "
                "WHERE model = ? AND local IS NOT NULL",
                (model,),
            )
        }
        index = self._read_snapshot(model, generation, len(ids))
        if index is None:
            index = self._build(model, ids)
            try:
                self._save_index(model, ModelIndex(index, ids, object_ids, poses), generation)
            except OSError as e:  # a full disk: SQLite is intact and the index is built, so serve on
                log.warning(
                    "could not save the %s index snapshot to %s (%s): serving from SQLite; it is rebuilt "
                    "at each start until it can be saved",
                    model,
                    self.dir,
                    e,
                )
                self._paths(model)[1].unlink(missing_ok=True)  # as in `_swap`: no tag for a file it lacks
        return ModelIndex(index, ids, object_ids, poses, local)

    def _paths(self, model: str) -> tuple[Path, Path]:
        p = self.dir / f"{model}.faiss"
        return p, p.with_name(p.name + ".json")

    def _read_snapshot(self, model: str, generation: int, ntotal: int) -> faiss.Index | None:
        path, tag_path = self._paths(model)
        if not path.is_file() or not tag_path.is_file():
            log.info("%s: no index snapshot, building it from SQLite", model)
            return None
        try:
            tag = json.loads(tag_path.read_text())
            data = path.read_bytes()
            if tag.get("generation") != generation:
                log.info("%s: index snapshot is stale, building it from SQLite", model)
                return None
            if tag.get("sha256") != hashlib.sha256(data).hexdigest():
                raise ValueError("checksum mismatch")
            index = faiss.deserialize_index(np.frombuffer(data, np.uint8))
            if index.ntotal != ntotal or index.d != self.dims[model] or tag.get("kind") != self.kind:
                raise ValueError(f"holds {index.ntotal} x {index.d}, SQLite {ntotal} x {self.dims[model]}")
        except Exception as e:
            log.warning("%s: index snapshot %s is corrupt (%s): building it from SQLite", model, path, e)
            return None
        self._tune(index)
        self._tags[model] = tag
        return index

    def _build(self, model: str, ids: np.ndarray) -> faiss.Index:
        dim = self.dims[model]
        desc = np.zeros((len(ids), dim), np.float32)
        rows = self._db.execute("SELECT descriptor FROM templates WHERE model = ? ORDER BY id", (model,))
        for i, (blob,) in enumerate(rows):
            desc[i] = np.frombuffer(blob, np.float32)
        if self.kind == "ivf" and len(ids) >= 39 * self.nlist:
            index: faiss.Index = faiss.IndexIVFFlat(faiss.IndexFlatL2(dim), dim, self.nlist)
            index.train(desc)
        else:
            index = faiss.IndexIDMap2(faiss.IndexFlatL2(dim))
        self._tune(index)
        if len(ids):
            index.add_with_ids(desc, ids)
        return index

    def _tune(self, index: faiss.Index) -> None:
        if (ivf := faiss.try_extract_index_ivf(index)) is not None:
            ivf.nprobe = self.nprobe

    def _save_index(self, model: str, mi: ModelIndex, generation: int) -> None:
        """Writes the snapshot file then its tag, each through a temporary file and an atomic rename."""
        path, tag_path = self._paths(model)
        data = faiss.serialize_index(mi.index).tobytes()
        tag = {
            "generation": generation,
            "ntotal": mi.size,
            "kind": self.kind,
            "sha256": hashlib.sha256(data).hexdigest(),
        }
        _write_atomic(path, data)
        _write_atomic(tag_path, json.dumps(tag).encode())
        self._tags[model] = tag


def _write_atomic(path: Path, content: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(content)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)  # a half-written file only takes the space a full disk lacks
        raise
