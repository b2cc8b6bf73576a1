"""What a Milvus replica sees: the records polled with a strong read, the snapshot rebuilt when they change, and the
sweep of what a replica killed mid-registration left behind."""

from __future__ import annotations

import json
import logging
import time
import zipfile
from collections.abc import Mapping
from typing import Any

import numpy as np

from index.store.milvus_snapshot import (
    DELETED,
    LIVE,
    PENDING,
    MilvusModel,
    MilvusSnapshot,
    short,
)
from index.store.milvus_trust import missing_files
from index.store.records import (
    ObjectRecord,
    StoreUnavailable,
    local_key,
)

log = logging.getLogger("index.store")

#: every this many polls (~0.25 s each) every live object's files are checked, not only the missing ones
FULL_CHECK_POLLS = 20


class MilvusPoll:
    """The polling, snapshot and sweep part of `MilvusStore` (its attributes declared here, set there)."""

    _generation: Any
    _local: dict[str, dict[int, dict[tuple[int, float, float], np.ndarray]]]
    _problem: str | None
    _trust: str | None
    _missing: dict[int, list[str]]
    _damaged: set[str]
    _directory_problem: Any  # MilvusTrust's
    _files_problem: Any  # MilvusTrust's
    _query: Any
    _records: dict[str, dict[str, Any]]
    _refreshing: Any
    _rows: dict[str, tuple[int, float, int]]
    _snap: Any
    _stop: Any
    client: Any
    collections: Any
    dims: Any
    files: Any
    objects_collection: Any
    poll_seconds: Any
    sweep_seconds: Any
    timeout: Any
    uri: Any
    _call: Any  # MilvusStore's
    _remove_remains: Any  # MilvusStore's
    search_raw: Any  # MilvusStore's

    def _sweep(self) -> None:
        """Removes what registrations killed midway and deletions cut short left: pending records older
        than `sweep_seconds` (turned deleted), and the templates of deleted objects."""
        now = time.time()
        rows = self._query(f"state == {PENDING} and updated < {now - self.sweep_seconds}", ["*"])
        for r in rows:
            log.warning("object %d (%s): a registration left unfinished, swept", r["object_id"], r["name"])
            r.update(state=DELETED, updated=now)
            self.client.upsert(self.objects_collection, [r], timeout=self.timeout)
        dead = self._query(f"state == {DELETED} and object_id >= 0", ["object_id"])  # not the marker
        self._remove_remains(sorted({int(r["object_id"]) for r in dead}))

    def _load_local(self, oid: int, model: str) -> dict[tuple[int, float, float], np.ndarray]:
        name = f"local/{self.collections[model]}/{oid}.npz"
        try:
            arrays = self.files.read_arrays(name)
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as e:  # damaged: as good as missing
            log.warning("object %d: %s is damaged (%s)", oid, name, short(e))
            self._damaged.add(name)
            return {}
        if arrays is None:
            return {}
        return {
            local_key(oid, az, el): f
            for (az, el), f in zip(arrays["viewpoints"], arrays["local"], strict=True)
        }

    def _to_record(self, r: Mapping[str, Any]) -> ObjectRecord:
        counts = json.loads(r["templates"])
        return ObjectRecord(
            int(r["object_id"]),
            r["name"],
            r["symmetry"],
            int(r["faces"]),
            float(r["created"]),
            {m: int(counts[c]) for m, c in self.collections.items() if c in counts},
            json.loads(r["extra"]),
        )

    def _empty(self) -> MilvusSnapshot:
        models = {m: MilvusModel(0, {}) for m in self.dims}
        return MilvusSnapshot(0, {}, models, self, "")

    def _put(self, record: dict[str, Any]) -> None:
        """This replica's own write, in its next snapshot at once (the others see it at their next poll)."""
        with self._refreshing:
            self._rows[record["token"]] = (
                int(record["state"]),
                float(record["updated"]),
                int(record["object_id"]),
            )
            if record["state"] == LIVE:
                self._records[record["token"]] = record
            else:
                self._records.pop(record["token"], None)
            self._rebuild()

    def _refresh(self) -> None:
        """Reads the records (strong) and swaps in a snapshot when anything changed."""
        with self._refreshing:
            rows = self._query("object_id >= 0", ["token", "object_id", "state", "updated"])
            seen = {r["token"]: (int(r["state"]), float(r["updated"]), int(r["object_id"])) for r in rows}
            changed = [t for t, su in seen.items() if self._rows.get(t) != su]
            gone = [t for t in self._rows if t not in seen]
            if not changed and not gone:
                return
            fresh = [t for t in changed if seen[t][0] == LIVE]
            got: set[str] = set()
            for s in range(0, len(fresh), 1000):
                part = fresh[s : s + 1000]
                # the strong read above has made the query node current: an "Eventually" read of what it
                # listed costs no wait for a time tick; a record it misses is fetched at the next poll
                for r in self._query(f"token in {json.dumps(part)}", ["*"], consistency="Eventually"):
                    if (int(r["state"]), float(r["updated"]), int(r["object_id"])) == seen[r["token"]]:
                        self._records[r["token"]] = r
                        got.add(r["token"])
            for t in list(self._records):
                if seen.get(t, (DELETED, 0.0, 0))[0] != LIVE:
                    del self._records[t]
            for t in set(fresh) - got:
                del seen[t]  # not fetched: still "changed" at the next poll
            self._rows = seen
            self._rebuild()

    def _rebuild(self) -> None:
        """The next snapshot from the records as known now (the caller holds `_refreshing`)."""
        live = {int(r["object_id"]): self._to_record(r) for r in self._records.values()}
        self._check_files(only_missing=False)
        damaged = len(self._damaged)
        for m, cache in self._local.items():
            for oid in [o for o in cache if o not in live]:
                del cache[oid]
            for oid in live:
                if oid not in cache:
                    cache[oid] = self._load_local(oid, m)
        models = {}
        for m, cache in self._local.items():
            flat: dict[tuple[int, float, float], np.ndarray] = {}
            for feats in cache.values():
                flat.update(feats)
            size = sum(rec.templates.get(m, 0) for rec in live.values())
            models[m] = MilvusModel(size, flat)
        if len(self._damaged) != damaged:  # found damaged while reading: not answered from
            self._check_files(only_missing=False)
        hidden = sorted({o for st, _, o in self._rows.values() if st != LIVE} - set(live))
        if not hidden:
            expr = ""
        elif len(hidden) <= len(live):
            expr = f"object_id not in {hidden}"
        else:
            expr = f"object_id in {sorted(live)}"
        self._generation += 1
        self._snap = MilvusSnapshot(self._generation, live, models, self, expr)

    def _loaded(self) -> bool:
        from pymilvus.client.types import LoadState

        for c in [self.objects_collection, *self.collections.values()]:
            state = self.client.get_load_state(c, timeout=self.timeout)["state"]
            if state != LoadState.Loaded:
                return False
        return True

    def _check_files(self, only_missing: bool) -> set[int]:
        """`_missing` and `_trust` again: the live objects' files (those known missing only, or all), then
        the directory. Returns the objects whose files came back, their local features dropped from the cache
        to be read again (the caller holds `_refreshing` and rebuilds when any came back)."""
        was = self._missing
        records = {int(r["object_id"]): r for r in self._records.values()}
        for name in list(self._damaged):  # mended since?
            try:
                if self.files.read_arrays(name) is not None:
                    self._damaged.discard(name)
            except (OSError, ValueError, KeyError, zipfile.BadZipFile):
                pass
        missing = {o: n for o, n in was.items() if o in records} if only_missing else {}
        for oid in was if only_missing else records:
            if oid not in records:
                continue
            counts = json.loads(records[oid]["templates"])
            names = missing_files(self.files, oid, counts, self.collections)
            names += [
                n for n in sorted(self._damaged) if n.endswith(f"/{oid}.npz") and self.files.path(n).is_file()
            ]
            if names:
                missing[oid] = names
            else:
                missing.pop(oid, None)
        back = {o for o in was if o in records and o not in missing}
        for oid in back:
            log.info("object %d: its files are there again", oid)
            for cache in self._local.values():
                cache.pop(oid, None)
            self._damaged = {n for n in self._damaged if not n.endswith(f"/{oid}.npz")}
        for oid in set(missing) - set(was):
            log.warning("object %d: missing from %s: %s", oid, self.files.root, ", ".join(missing[oid]))
        self._missing = missing
        self._trust = self._directory_problem() or self._files_problem(missing, self.files.root)
        return back

    def _sweeps(self) -> None:
        while not self._stop.wait(self.sweep_seconds / 2):
            try:
                self._call(self._sweep)
            except StoreUnavailable as e:  # the poll reports it
                log.debug("sweep: %s", e)
            except Exception:
                log.exception("sweeping the template store")

    def _poll(self) -> None:
        polls = 0
        while not self._stop.wait(self.poll_seconds):
            try:
                self._call(self._refresh)
                polls += 1
                with self._refreshing:  # what is missing, every poll; every object, every ~5 s
                    if self._check_files(only_missing=polls % FULL_CHECK_POLLS != 0):
                        self._rebuild()
                if self._problem is not None:
                    # back after a restart: ready once every collection is loaded again (Milvus reloads
                    # them itself, ~20 s here), so that searches work, not only the record reads
                    if not self._call(self._loaded):
                        self._problem = (
                            f"the template store (Milvus at {self.uri}) is loading its collections"
                        )
                        continue
                    log.info("the template store (Milvus at %s) answers again", self.uri)
                self._problem = None
            except StoreUnavailable as e:
                if self._problem is None:
                    log.warning("%s", e)
                self._problem = str(e)
            except Exception as e:  # never let the poller die: the replica would stop seeing changes
                log.exception("polling the template store")
                self._problem = f"the template store poll failed: {short(e)}"
