"""The embedded template store (the default, `POSEDESC_STORE=embedded`): descriptors of every object's
templates, one FAISS index per model in memory, SQLite as truth, all in one data directory that one
process owns.

Layout of a data directory:
- `store.sqlite`: objects (name, symmetry, the mesh as GLB so templates can be made again), templates
  (object, model, azimuth, elevation, in-plane, the descriptor itself), the models' fingerprints and a
  `generation` counter bumped by every write. One SQLite transaction per write, so after a crash an
  object is wholly present or wholly absent, for every model at once.
- `<model>.faiss` + `<model>.faiss.json`: a snapshot of that model's index (`index.store.snapshot_files`), a
  cache of SQLite's rows for a quick start, written after each write returns, on a thread of its own
  (`_swap`; `flush` waits for it, `close` too): one missing or stale after a crash is rebuilt from SQLite.
- `local/`: the local features, one memory-mapped file per object and model (`index.store.local_files`).
  A damaged `store.sqlite` (SQLite's own `quick_check` fails) is refused with a one-line `StoreError`.

A full disk: a write that SQLite cannot commit is rolled back and raises `OSError(ENOSPC)`; the store keeps
its previous state. A snapshot that cannot be written after a commit is only a warning (its tag is
removed, so it is rebuilt at the next start); so is one rebuilt on open that cannot be saved.

Two models whose templates are the same (the RGB-D model takes the rgb model's, `index.templates.register.template_twins`:
the same poses, descriptors and local features, object for object) share one `ModelIndex` in memory and one
snapshot file: the second's tag says `same_as` the first (`_twin`). They part when a write gives them
different templates (`_own`).

Readers never see a half-added object: the live state is an immutable `FaissSnapshot` (indexes +
metadata). A write builds the next one on copies (copy-on-write) and swaps the reference under a lock; a
search runs lock-free on whichever snapshot it picked up. Writers are serialised."""

from __future__ import annotations

import errno
import json
import logging
import sqlite3
import threading
import time
from collections.abc import Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import faiss
import numpy as np

from index.store.local_files import LocalFiles, keep_twins, marker
from index.store.model_indexes import ModelIndexes, twin_of
from index.store.records import Match, NameTaken, ObjectRecord, StoreError, TemplateSet, check_set, local_key
from index.store.search import FaissSnapshot, ModelIndex
from index.store.snapshot_files import (
    AUTO_IVF_MIN,
    INDEX_KINDS,
    grown,
    write_atomic,
)
from index.store.sqlite_file import SCHEMA, check_sqlite, disk_full, recorded_models

log = logging.getLogger("index.store")


class EmbeddedStore(ModelIndexes):
    """Templates of all objects for a fixed set of models, persisted in `data_dir`.

    `models` maps a model name to (descriptor dim, fingerprint of the model file). A model whose
    fingerprint changed since the last run has its templates dropped: `missing()` then lists the
    objects to embed again (see `register.reembed`)."""

    def __init__(
        self,
        data_dir: str | Path,
        models: Mapping[str, tuple[int, str]],
        kind: str = "auto",
        nlist: int = 256,
        nprobe: int = 16,
        ivf_min: int = AUTO_IVF_MIN,
    ):
        if kind not in INDEX_KINDS:
            raise StoreError(f"unknown index kind {kind!r}; use one of {INDEX_KINDS}")
        if not models:
            raise StoreError("a store needs at least one model")
        self.dir = Path(data_dir)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.dims = {m: int(d) for m, (d, _) in models.items()}
        self.kind, self.nlist, self.nprobe = kind, nlist, nprobe
        self.ivf_min = ivf_min  # "auto": IVF from this many templates (`index.store.snapshot_files.ivf_from`)
        self._write = threading.Lock()
        self._tags: dict[str, dict] = {}  # the snapshot files' tags, as last written
        #: the index each model's snapshot file holds (as last written: `_sync`), and the state whose
        #: files are still to be written, by the one thread that writes them
        self._written: dict[str, ModelIndex] = {}
        self._pending: FaissSnapshot | None = None
        self._pending_lock = threading.Lock()
        self._writer = ThreadPoolExecutor(1, thread_name_prefix="snapshot-files")
        self._files = LocalFiles(self.dir, {m: fp for m, (_, fp) in models.items()})
        path = self.dir / "store.sqlite"
        try:
            self._db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")  # a committed registration survives a power cut
            self._db.execute("PRAGMA foreign_keys=ON")
            check_sqlite(self._db, path)
            self._db.executescript(SCHEMA)
            columns = {row[1] for row in self._db.execute("PRAGMA table_info(templates)")}
            if "local" not in columns:  # a store made before local features existed
                self._db.execute("ALTER TABLE templates ADD COLUMN local BLOB")
            self._forget_changed_models(models)
            self._snap = self._load()
            self._written = {m: mi for m, mi in self._snap.models.items() if m in self._tags}
        except sqlite3.DatabaseError as e:  # damage quick_check cannot see: a bad row, a bad descriptor
            raise StoreError(f"{path} is not a usable store: {e}") from None
        except StoreError:
            self._db.close()
            raise

    # -- reading -----------------------------------------------------------------------------------

    @property
    def snapshot(self) -> FaissSnapshot:
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
            oid = None
            try:
                with self._transaction() as cur:
                    row = cur.execute("SELECT id FROM objects WHERE name = ? LIMIT 1", (name,)).fetchone()
                    if row is not None:
                        raise NameTaken(name, int(row[0]))
                    created = time.time()
                    cur.execute(
                        "INSERT INTO objects (name, symmetry, faces, created, extra, mesh) "
                        "VALUES (?, ?, ?, ?, ?, ?)",
                        (name, symmetry, int(faces), created, json.dumps(dict(extra or {})), mesh),
                    )
                    oid = int(cur.lastrowid)  # type: ignore[arg-type]
                    twins = self._twins_in(templates)
                    new_ids = {
                        m: self._insert_templates(cur, oid, m, ts, twins.get(m))
                        for m, ts in templates.items()
                    }
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
            except BaseException:
                if oid is not None:  # files written for a write that was not committed (the id comes again)
                    self._files.remove(oid)
                raise
            self._swap(snap)
        return rec

    def add_templates(self, object_id: int, model: str, ts: TemplateSet) -> None:
        """Adds one model's templates to an existing object (re-embedding after a model changed)."""
        self._check_set(model, ts)
        with self._write:
            old = self._snap.objects.get(object_id)
            if old is None:
                raise KeyError(object_id)
            try:
                with self._transaction() as cur:
                    ids = self._insert_templates(cur, object_id, model, ts)
                    counts = {**old.templates, model: old.templates.get(model, 0) + len(ids)}
                    rec = replace(old, templates=counts)
                    snap = self._next(cur, add={model: (object_id, ids, ts)}, put=rec)
            except BaseException:
                self._files.remove(object_id, [model])
                raise
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
            self._files.remove(object_id)  # snapshots still searching map them on: Linux keeps the pages
        return True

    def flush(self) -> None:
        """Waits until the snapshot files are written for the writes made so far (`_swap`)."""
        self._writer.submit(lambda: None).result()

    def close(self) -> None:
        self._writer.shutdown(wait=True)  # the snapshot files of the last write, then no more
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
            if disk_full(e):
                raise OSError(errno.ENOSPC, f"disk full: could not write {self.dir / 'store.sqlite'}") from e
            raise

    def _twins_in(self, add: Mapping[str, TemplateSet]) -> dict[str, str]:
        """The models of a write that go on sharing an earlier model's index (`_next`): model -> that one."""
        return {
            m: src
            for m in add
            if (src := twin_of(self._snap.models, m)) is not None
            and src in add
            and _same_set(add[src], add[m])
        }

    def _check_set(self, model: str, ts: TemplateSet) -> None:
        check_set(model, self.dims, ts)

    def _insert_templates(
        self, cur: sqlite3.Cursor, oid: int, model: str, ts: TemplateSet, same_as: str | None = None
    ) -> np.ndarray:
        """`ts` as `model`'s rows of object `oid`; the local features of a model whose templates are
        `same_as`'s in this write are not stored twice: its rows say where they are (`index.store.local_files.marker`)."""
        desc = np.ascontiguousarray(ts.descriptors, np.float32)
        poses = np.asarray(ts.poses, float)
        local: list[bytes | None] = [None] * len(desc)
        if ts.local_rows is not None and ts.local is not None:
            for r, f in zip(ts.local_rows, np.asarray(ts.local, np.float16), strict=True):
                local[int(r)] = f.tobytes() if same_as is None else marker(same_as)
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
    ) -> FaissSnapshot:
        """The snapshot after this write (copies of the changed indexes), with the generation bumped."""
        cur.execute("UPDATE meta SET value = CAST(value AS INTEGER) + 1 WHERE key = 'generation'")
        old = self._snap
        objects = dict(old.objects)
        models = dict(old.models)
        if remove is not None:
            del objects[remove]
            done: dict[int, ModelIndex] = {}  # a model sharing another's index: the same result
            for m, mi in old.models.items():
                gone = mi.object_ids == remove
                if id(mi) in done:
                    models[m] = done[id(mi)]
                elif gone.any():
                    index = faiss.clone_index(mi.index)
                    index.remove_ids(mi.ids[gone])
                    local = {k: v for k, v in mi.local.items() if k[0] != remove}
                    models[m] = ModelIndex(index, mi.ids[~gone], mi.object_ids[~gone], mi.poses[~gone], local)
                done[id(mi)] = models[m]
        add = add or {}
        for m in [m for m in self.dims if m in add]:  # a twin after the model it shares with
            oid, ids, ts = add[m]
            mi = old.models[m]
            if twin_of(old.models, m) is not None:  # after the loop
                continue
            index = faiss.clone_index(mi.index)
            index.add_with_ids(np.ascontiguousarray(ts.descriptors, np.float32), ids)
            index = grown(index, self.kind, self.nlist, self.nprobe, self.ivf_min)
            local = dict(mi.local)
            if ts.local_rows is not None and ts.local is not None:
                order = np.argsort(ts.local_rows, kind="stable")  # the file's rows in template id order
                rows = self._files.write(m, oid, np.asarray(ts.local, np.float16)[order])
                for r, f in zip(np.asarray(ts.local_rows)[order], rows, strict=True):
                    p = ts.poses[int(r)]
                    local[local_key(oid, p[0], p[1])] = f
            models[m] = ModelIndex(
                index,
                np.concatenate([mi.ids, ids]),  # new ids are larger than all old ones: still ascending
                np.concatenate([mi.object_ids, np.full(len(ids), oid, np.int64)]),
                np.concatenate([mi.poses, np.asarray(ts.poses, np.float32)]),
                local,
            )
        for m in self.dims:
            if (src := twin_of(old.models, m)) is None or not (m in add or src in add):
                continue
            if m in add and src in add and _same_set(add[src][2], add[m][2]):  # as `_twins_in`
                models[m] = models[src]
            else:  # they part: an index of its own, from SQLite (this write's rows too); the shared one's
                models[m] = self._own(m)  # ids are its twin's
        if put is not None:
            objects[put.object_id] = put
        return FaissSnapshot(old.generation + 1, objects, models)

    def _swap(self, snap: FaissSnapshot) -> None:
        """Makes `snap` the live state, and has its snapshot files written after the caller returns: a
        registration need not wait for an index of ~10^5 templates to be written and synced to disk
        (0.3-0.9 s of its store step on 2 cores, `posedesc bench`), which is only a cache of SQLite (a
        stale one is rebuilt at the next start). Writes that queue up meanwhile are written once, as the
        newest of them."""
        self._snap = snap  # one reference assignment: readers get the old or the new state, never a mix
        with self._pending_lock:
            self._pending = snap
        self._writer.submit(self._sync_pending)

    def _sync_pending(self) -> None:
        with self._pending_lock:
            snap, self._pending = self._pending, None
        if snap is None:  # written already, with a later write's state
            return
        try:
            self._sync(snap)
        except Exception:  # not an OSError (those are warnings in `_sync_file`): say so, and go on serving
            log.exception("could not write the index snapshots to %s", self.dir)

    def _sync(self, snap: FaissSnapshot) -> None:
        """The snapshot files brought to `snap`: the indexes not on disk written again, the others' tags
        moved to its generation."""
        changed = [m for m, mi in snap.models.items() if self._written.get(m) is not mi]
        if len(changed) > 1:  # a file a thread: hashing, writing and fsync release the GIL
            with ThreadPoolExecutor(len(changed), thread_name_prefix="snapshot") as pool:
                list(pool.map(lambda m: self._sync_file(m, snap, True), changed))
        elif changed:
            self._sync_file(changed[0], snap, True)
        for m in snap.models.keys() - set(changed):
            self._sync_file(m, snap, False)

    def _sync_file(self, m: str, snap: FaissSnapshot, changed: bool) -> None:
        """Model `m`'s snapshot file brought to `snap`: written again if its index `changed`, else only
        its tag moved to the new generation."""
        try:
            if changed:
                self._save_index(m, snap.models[m], snap.generation, twin_of(snap.models, m))
                self._written[m] = snap.models[m]
            elif m in self._tags:  # unchanged index: only its tag moves to the new generation
                tag = {**self._tags[m], "generation": snap.generation}
                write_atomic(self._paths(m)[1], json.dumps(tag).encode())
                self._tags[m] = tag
        except OSError as e:  # the write is committed; a stale snapshot is rebuilt at the next start
            log.warning("could not write the %s index snapshot to %s: %s", m, self.dir, e)
            # Forget the tag and remove its file: a later write must not re-tag a file that lacks
            # this write as current (ntotal would catch most such files, not all).
            self._tags.pop(m, None)
            self._written.pop(m, None)  # so the next write writes it whole
            self._paths(m)[1].unlink(missing_ok=True)

    def _forget_changed_models(self, models: Mapping[str, tuple[int, str]]) -> None:
        known = recorded_models(self._db)
        for name, (dim, fingerprint) in models.items():
            if known.get(name) == (dim, fingerprint):
                continue
            if name in known:
                log.warning("model %s changed since its templates were made: they will be made again", name)
            with self._db:
                self._db.execute("BEGIN IMMEDIATE")
                keep_twins(self._db, name)
                self._db.execute("DELETE FROM templates WHERE model = ?", (name,))
                self._db.execute("INSERT OR REPLACE INTO models VALUES (?, ?, ?)", (name, fingerprint, dim))
                self._db.execute(
                    "UPDATE meta SET value = CAST(value AS INTEGER) + 1 WHERE key = 'generation'"
                )

    def problem(self) -> str | None:
        return None  # in this process: it serves as long as the process does


def _same_set(a: TemplateSet, b: TemplateSet) -> bool:
    """Whether two models' templates of an object are the same: poses, descriptors and local features."""
    if a is b:
        return True
    if (a.local is None) != (b.local is None):
        return False
    same = np.array_equal(a.poses, b.poses) and np.array_equal(a.descriptors, b.descriptors)
    if a.local is None or b.local is None:
        return same
    return (
        same
        and np.array_equal(a.local_rows, b.local_rows)  # type: ignore[arg-type]
        and np.array_equal(np.asarray(a.local, np.float16), np.asarray(b.local, np.float16))
    )
