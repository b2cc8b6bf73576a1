"""The template store on Milvus (`POSEDESC_STORE=http://host:19530`): any number of service replicas share
one collection of templates, see each other's registrations and deletions within a bound, and no replica
holds the truth in a local file.

Where things live:
- Milvus, collection `<prefix>_objects`: one record per object ever registered (its id, name, symmetry,
  `state` pending / live / deleted, template counts, extra such as the surface offsets). Records are never
  removed: a deleted object keeps a tombstone, so an id is never given twice and "this store has held
  objects" (demo seeding) is a fact of the store, not of a replica.
- Milvus, one collection per model *and model file* (`<prefix>_t_<model>_<fingerprint>`): each template's
  descriptor (HNSW, L2) with its object id and pose. A retrained model gets a new collection, so replicas
  of the old and new model can run side by side during a rollout.
- The data directory, shared by the replicas (a volume every replica mounts; `index.store.shared_files`): each
  object's mesh (GLB, to make templates again when a model changes) and local features (the re-ranking's,
  ~12 kB a viewpoint: too large for a Milvus 2.3 field, and read once per object by each replica), the
  meta flags and the job states. Milvus stores no files; see docs/scaling.md for why a shared directory
  rather than a bucket.

Milvus has no transaction across collections, so a registration is made all-or-nothing by its record: the
record is written first as *pending* (this claims the id and the name), then the templates, then (once a
strong read sees every template) the record turns *live*. Searches filter on the object ids each replica
knows: pending and deleted objects' templates are never returned, so a replica killed mid-registration
leaves only a pending record and templates no one sees; a sweep removes them once the record is older than
`sweep_seconds`. A deletion turns the record *deleted* first (from then on no replica returns the object
once it has polled), then removes the templates and files.

Visibility: every replica polls the records with a strong read, `poll_seconds` (50 ms) after the last one
ended (a strong read waits for Milvus's 200 ms time tick, so a poll every ~0.25 s): a registration or
deletion on one replica is seen by the others within ~0.5 s, bounded by 1 s. Searches themselves are "Bounded" reads (~2 ms instead of ~200 ms for "Strong"): the
filter on known live ids, not the search's consistency, is what keeps deleted objects out.

Two registrations of one name on two replicas: both write a pending record, then read the records back;
the earlier (created, token) wins, the other removes its record and answers NameTaken. Ids are claimed
the same way (the largest id ever given + 1).
"""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from index.store.milvus_collections import MilvusCollections
from index.store.milvus_poll import MilvusPoll
from index.store.milvus_snapshot import (
    DELETED,
    LIVE,
    PENDING,
    MilvusSnapshot,
    collection_name,
    short,
)
from index.store.milvus_trust import FILES_KEY, MilvusTrust, counts_with_files, files_written
from index.store.records import (
    Match,
    NameTaken,
    ObjectRecord,
    StoreError,
    StoreUnavailable,
    TemplateSet,
    check_set,
)
from index.store.shared_files import SharedFiles

log = logging.getLogger("index.store")
# pymilvus logs every failed call with its traceback at ERROR; this module says what failed in one line
logging.getLogger("pymilvus").setLevel(logging.CRITICAL)

INSERT_BATCH = 20_000
T = TypeVar("T")


class MilvusStore(MilvusCollections, MilvusPoll, MilvusTrust):
    """Templates of all objects for a fixed set of models in the Milvus at `uri`; meshes, local features
    and meta flags in `data_dir`, which every replica shares. The same interface as the embedded store
    (`index.store.TemplateStore`)."""

    def __init__(
        self,
        uri: str,
        data_dir: str | Path,
        models: Mapping[str, tuple[int, str]],
        prefix: str = "posedesc",
        poll_seconds: float = 0.05,
        timeout: float = 5.0,
        sweep_seconds: float = 600.0,
        hnsw_m: int = 16,
        ef_construction: int = 200,
        ef: int = 128,
    ):
        if not models:
            raise StoreError("a store needs at least one model")
        from pymilvus import MilvusClient

        self.uri, self.prefix, self.timeout = uri, prefix, timeout
        self.poll_seconds, self.sweep_seconds = poll_seconds, sweep_seconds
        self.ef, self._index = ef, {"M": hnsw_m, "efConstruction": ef_construction}
        self.dims = {m: int(d) for m, (d, _) in models.items()}
        self.collections = {m: collection_name(prefix, m, fp) for m, (_, fp) in models.items()}
        self.objects_collection = f"{prefix}_objects"
        self.files = SharedFiles(Path(data_dir))
        self._write = threading.Lock()  # this replica's writers, one at a time (as the embedded store)
        self._refreshing = threading.Lock()
        self._stop = threading.Event()
        self._problem: str | None = None
        self._rows: dict[str, tuple[int, float, int]] = {}  # token -> (state, updated, object_id) as polled
        self._records: dict[str, dict[str, Any]] = {}  # token -> full record of live objects
        self._local: dict[str, dict[int, dict[tuple[int, float, float], np.ndarray]]] = {
            m: {} for m in models
        }
        self._generation = 0
        try:
            self.client = MilvusClient(uri, timeout=timeout)
        except Exception as e:
            raise StoreUnavailable(
                f"the template store (Milvus at {uri}) does not answer: {short(e)}"
            ) from None
        self._call(self._create_collections)
        self.store_id: str | None = None
        self._missing: dict[int, list[str]] = {}  # live objects whose files this replica lacks
        self._damaged: set[str] = set()  # local feature files that would not read
        self._trust: str | None = None  # why this replica cannot answer as the others do (milvus_trust)
        self.store_id = self._call(self._establish_store_id)
        self._snap = self._empty()
        self._call(self._refresh)
        self._call(self._sweep)
        self._poller = threading.Thread(target=self._poll, name="milvus-poll", daemon=True)
        self._poller.start()
        # apart from the poll: a sweep's deletes take a time tick each and must not delay what replicas see
        self._sweeper = threading.Thread(target=self._sweeps, name="milvus-sweep", daemon=True)
        self._sweeper.start()

    # -- reading -----------------------------------------------------------------------------------

    @property
    def snapshot(self) -> MilvusSnapshot:
        return self._snap

    def search(self, model: str, queries: np.ndarray, k: int) -> list[list[Match]]:
        return self._snap.search(model, queries, k)

    def search_raw(self, model: str, queries: np.ndarray, n: int, expr: str) -> list[list[dict]]:
        q = np.ascontiguousarray(queries, np.float32).reshape(len(queries), self.dims[model])
        return self._call(
            self.client.search,
            self.collections[model],
            data=q.tolist(),
            limit=int(n),
            filter=expr,
            output_fields=["object_id", "azimuth", "elevation", "inplane"],
            search_params={"metric_type": "L2", "params": {"ef": max(self.ef, int(n))}},
            consistency_level="Bounded",
            timeout=self.timeout,
        )

    def missing(self) -> dict[str, list[int]]:
        snap = self._snap
        return {
            m: [oid for oid, rec in snap.objects.items() if rec.templates.get(m, 0) == 0] for m in self.dims
        }

    def mesh_bytes(self, object_id: int) -> bytes | None:
        return self.files.read(f"meshes/{int(object_id)}.glb")

    def get_meta(self, key: str) -> str | None:
        data = self.files.read(f"meta/{key}")
        return None if data is None else data.decode()

    def set_meta(self, key: str, value: str) -> None:
        self.files.write(f"meta/{key}", value.encode())

    def has_held_objects(self) -> bool:
        """Whether any object was ever registered here, by any replica (records are never removed)."""
        rows = self._call(self._query, "object_id >= 0", ["token"], limit=1)
        return len(rows) > 0

    def problem(self) -> str | None:
        """Why this replica cannot answer now: Milvus unreachable or loading, or it could not answer as the
        other replicas do (`index.store.milvus_trust`: not the store's directory, live objects' files missing)."""
        return self._problem or self._trust

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
        """Adds an object with its templates for every model; all-or-nothing as seen from every replica
        (the record turns live last). Raises NameTaken when a live or pending object has the name."""
        for m, ts in templates.items():
            check_set(m, self.dims, ts)
        if (same := self._snap.named(name)) is not None:
            raise NameTaken(name, same.object_id)
        extra_text = json.dumps(dict(extra or {}))
        if len(extra_text) > 60_000:
            raise ValueError("an object's extra data must stay under 60,000 characters of JSON")
        counts = {self._key(m): len(ts.poses) for m, ts in templates.items()}
        local = [
            self._key(m) for m, ts in templates.items() if ts.local is not None and ts.local_rows is not None
        ]
        with self._write:
            token, created = uuid.uuid4().hex, time.time()
            record = {
                "token": token,
                "name": name,
                "state": PENDING,
                "symmetry": symmetry,
                "faces": int(faces),
                "created": created,
                "updated": created,
                "templates": counts_with_files(counts, files_written(mesh is not None, local)),
                "extra": extra_text,
                "v": [0.0, 0.0],
            }
            oid = self._call(self._claim, record)
            try:
                if mesh is not None:
                    self.files.write(f"meshes/{oid}.glb", mesh)
                for m, ts in templates.items():
                    self._save_local(oid, m, ts)
                    self._call(self._insert, m, oid, ts)
                self._call(self._wait_visible, oid, {m: len(ts.poses) for m, ts in templates.items()})
                self._call(self._go_live, record)
            except BaseException:
                self._undo(oid, token)
                raise
            self._put(record)
        return self._to_record(record)

    def add_templates(self, object_id: int, model: str, ts: TemplateSet) -> None:
        """Adds one model's templates to a live object (re-embedding after a model changed). Every replica
        of a new model finds the same objects missing at start: the first to claim the (object, model)
        in the shared directory makes them, the others leave it (they see them at their next poll)."""
        check_set(model, self.dims, ts)
        if not self.files.claim(f"claims/{self.collections[model]}/{int(object_id)}", self.sweep_seconds):
            log.info("object %d, %s: another replica makes these templates", object_id, model)
            return
        with self._write:
            rows = self._call(self._query, f"object_id == {int(object_id)} and state == {LIVE}", ["*"])
            if not rows:
                raise KeyError(object_id)
            record = rows[0]
            self._save_local(object_id, model, ts)
            self._call(self._insert, model, object_id, ts)
            self._call(self._wait_visible, object_id, {model: len(ts.poses)})
            counts = json.loads(record["templates"])
            counts[self._key(model)] = counts.get(self._key(model), 0) + len(ts.poses)
            if FILES_KEY in counts and ts.local is not None and ts.local_rows is not None:
                written = counts[FILES_KEY]
                written["local"] = sorted({*written.get("local", []), self._key(model)})
            record.update(templates=json.dumps(counts), updated=time.time())
            self._call(self.client.upsert, self.objects_collection, [record], timeout=self.timeout)
            self._put(record)

    def remove_object(self, object_id: int) -> bool:
        """Removes an object: its record turns deleted (no replica returns it once it has polled), then its
        templates and files go. False when no live object has this id."""
        oid = int(object_id)
        with self._write:
            record = next((dict(r) for r in self._records.values() if int(r["object_id"]) == oid), None)
            if record is None:  # not known here (yet): registered on another replica since the last poll?
                rows = self._call(self._query, f"object_id == {oid} and state == {LIVE}", ["*"])
                if not rows:
                    return False
                record = rows[0]
            record.update(state=DELETED, updated=time.time())
            self._call(self.client.upsert, self.objects_collection, [record], timeout=self.timeout)
            self._put(record)
        try:
            self._remove_remains([oid])
        except StoreUnavailable as e:  # the deletion stands (its record); the sweep finishes it
            log.warning("object %d deleted; its templates are removed later: %s", oid, e)
        return True

    def close(self) -> None:
        self._stop.set()
        self._poller.join(timeout=5)
        self._sweeper.join(timeout=5)
        try:
            self.client.close()
        except Exception as e:  # closing a client whose server is gone
            log.debug("closing the Milvus client: %s", e)

    # -- internals ---------------------------------------------------------------------------------

    def _call(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Any Milvus call: its failure is `StoreUnavailable` with one line (the service answers 503)."""
        try:
            return fn(*args, **kwargs)
        except (StoreError, NameTaken, KeyError, ValueError):
            raise
        except Exception as e:
            raise StoreUnavailable(
                f"the template store (Milvus at {self.uri}) does not answer: {short(e)}"
            ) from None

    def _key(self, model: str) -> str:
        return self.collections[model]

    def _claim(self, record: dict[str, Any]) -> int:
        """Writes `record` pending under the next free id; the earliest claim of an id or a name wins."""
        me = (record["created"], record["token"])
        oid = 1 + max((o for _, _, o in self._rows.values()), default=0)  # as last polled: checked below
        for _ in range(50):
            self.client.insert(self.objects_collection, [{**record, "object_id": oid}], timeout=self.timeout)
            rows = self._query(
                f"object_id >= {oid} or state != {DELETED}",
                ["token", "object_id", "name", "state", "created"],
            )
            rivals = [
                r
                for r in rows
                if r["token"] != record["token"]
                and (r["object_id"] == oid or (r["name"] == record["name"] and r["state"] != DELETED))
                # a live or deleted record has won already, whatever the replicas' clocks say
                and (r["state"] != PENDING or (r["created"], r["token"]) < me)
            ]
            if not rivals:
                record["object_id"] = oid
                return oid
            self.client.delete(self.objects_collection, ids=[record["token"]], timeout=self.timeout)
            same_name = [r for r in rivals if r["name"] == record["name"]]
            if same_name:
                raise NameTaken(record["name"], int(same_name[0]["object_id"]))
            oid = 1 + max(int(r["object_id"]) for r in rows)
        raise StoreUnavailable("could not claim an object id: too many concurrent registrations")

    def _insert(self, model: str, oid: int, ts: TemplateSet) -> None:
        desc = np.ascontiguousarray(ts.descriptors, np.float32)
        poses = np.asarray(ts.poses, np.float32)
        for s in range(0, len(desc), INSERT_BATCH):
            rows = [
                {
                    "object_id": oid,
                    "azimuth": float(p[0]),
                    "elevation": float(p[1]),
                    "inplane": float(p[2]),
                    "descriptor": d.tolist(),
                }
                for p, d in zip(poses[s : s + INSERT_BATCH], desc[s : s + INSERT_BATCH], strict=True)
            ]
            self.client.insert(self.collections[model], rows, timeout=self.timeout)

    def _wait_visible(self, oid: int, expected: Mapping[str, int]) -> None:
        """A strong count of the object's templates: once it sees them all, so does every later search."""

        def count(m: str) -> int:
            rows = self.client.query(
                self.collections[m],
                filter=f"object_id == {oid}",
                output_fields=["count(*)"],
                consistency_level="Strong",
                timeout=self.timeout,
            )
            return int(rows[0]["count(*)"])

        # one strong read per collection (each its own channel), side by side: ~0.2 s, not ~0.2 s each
        with ThreadPoolExecutor(len(expected)) as pool:
            counts = dict(zip(expected, pool.map(count, expected), strict=True))
        for m, n in expected.items():
            if counts[m] < n:
                raise StoreUnavailable(f"{m}: Milvus holds {counts[m]} of {n} templates just written")

    def _go_live(self, record: dict[str, Any]) -> None:
        if time.time() - record["created"] > self.sweep_seconds / 2:  # a sweep may have found it pending
            rows = self._query(f'token == "{record["token"]}"', ["state"])
            if not rows or rows[0]["state"] != PENDING:
                raise StoreUnavailable(
                    "the registration took longer than the sweep allows; nothing was stored"
                )
        record.update(state=LIVE, updated=time.time())
        self.client.upsert(self.objects_collection, [record], timeout=self.timeout)

    def _undo(self, oid: int, token: str) -> None:
        """Best effort after a failed registration; what is left (Milvus down) is pending, so swept later."""
        try:
            self._remove_remains([oid])
            self.client.delete(self.objects_collection, ids=[token], timeout=self.timeout)
        except Exception as e:
            log.warning("object %d: a failed registration is left pending for the sweep: %s", oid, short(e))

    def _remove_remains(self, oids: Sequence[int]) -> None:
        """Templates (every model collection of this prefix, old model files' too) and files of objects."""
        if not oids:
            return
        expr = f"object_id in {[int(o) for o in oids]}"
        colls = self._call(self.client.list_collections, timeout=self.timeout)
        mine = [c for c in colls if c.startswith(f"{self.prefix}_t_")]
        with ThreadPoolExecutor(max(1, len(mine))) as pool:  # each waits for a time tick: side by side
            list(
                pool.map(lambda c: self._call(self.client.delete, c, filter=expr, timeout=self.timeout), mine)
            )
        for oid in oids:
            self.files.remove(f"meshes/{oid}.glb")
            for coll in self.collections.values():
                self.files.remove(f"local/{coll}/{oid}.npz")

    def _save_local(self, oid: int, model: str, ts: TemplateSet) -> None:
        if ts.local_rows is None or ts.local is None:
            return
        rows = np.asarray(ts.local_rows, int)
        self.files.write_arrays(
            f"local/{self.collections[model]}/{oid}.npz",
            viewpoints=np.asarray(ts.poses, np.float64)[rows, :2],
            local=np.asarray(ts.local, np.float16),
        )
