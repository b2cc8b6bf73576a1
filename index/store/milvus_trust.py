"""What a Milvus replica checks before it answers, so that it answers as every other replica does or not at
all (docs/scaling.md, "What a replica checks"):

- **the shared directory is the store's.** The store's first replica draws a store id and writes it both
  into Milvus (a marker record: token `store`, object id -1, never live) and into the shared directory
  (`meta/store-id`). A replica whose directory holds another id, or none, while Milvus has one, mounts
  the wrong directory (each replica its own, the easy mistake on two machines): it would find no local
  features and rank by descriptors alone, or no meshes to fit. It is not ready, and says what to mount.
- **each live object's files are there.** A registration records in its Milvus record which files it
  wrote (`"_files"` in the record's template counts: the mesh, the local features of each model); a
  replica that lacks one of them (deleted, damaged, not yet synchronised) is not ready until they are.

While either is wrong, `problem()` says so: /readyz answers 503 with it and /recognize refuses with 503,
so a load balancer sends the queries to a replica that answers as the others do."""

from __future__ import annotations

import json
import logging
import time
import uuid
from collections.abc import Mapping
from typing import Any

from index.store.milvus_snapshot import DELETED, short
from index.store.records import StoreUnavailable
from index.store.shared_files import SharedFiles

log = logging.getLogger("index.store")

#: the marker record's token (its object id -1 and state deleted keep it out of every object query)
MARKER = "store"
#: the store id in the shared directory
ID_FILE = "meta/store-id"
#: the key of a record's template counts that lists the files its registration wrote
FILES_KEY = "_files"


def files_written(mesh: bool, local: list[str]) -> dict[str, Any]:
    """What a registration wrote to the shared directory: the mesh (when there was one), and the local
    features' file of each model collection in `local`."""
    return {"mesh": bool(mesh), "local": sorted(local)}


def missing_files(
    files: SharedFiles, oid: int, counts: Mapping[str, Any], collections: Mapping[str, str]
) -> list[str]:
    """The files a live object's record says were written and this replica's directory lacks (only those of
    the models it loads). A record from before the files were listed lists none."""
    written = counts.get(FILES_KEY) or {}
    wanted = [f"meshes/{oid}.glb"] if written.get("mesh") else []
    loaded = set(collections.values())
    wanted += [f"local/{c}/{oid}.npz" for c in written.get("local", []) if c in loaded]
    return [name for name in wanted if not files.path(name).is_file()]


class MilvusTrust:
    """The checks part of `MilvusStore` (its attributes declared here, set there)."""

    client: Any
    files: SharedFiles
    objects_collection: str
    timeout: float
    uri: str
    _query: Any  # MilvusCollections'
    store_id: str | None

    def _establish_store_id(self) -> str:
        """The store's id: the marker's in Milvus, or, for a new store, the shared directory's (drawn by the
        first replica to claim it) written into Milvus. Replicas starting together agree through the claim."""
        rows = self._query(f'token == "{MARKER}"', ["name"])
        if rows:
            return str(rows[0]["name"])
        here = self._directory_id()
        if here is None:
            if self.files.claim(ID_FILE + ".claim", stale_seconds=60.0):
                self.files.write(ID_FILE, uuid.uuid4().hex.encode())
            end = time.monotonic() + 30
            while (here := self._directory_id()) is None:  # another replica claimed it: its id comes
                if time.monotonic() > end:
                    raise StoreUnavailable(f"no store id appeared in {self.files.path(ID_FILE)}")
                time.sleep(0.05)
        now = time.time()
        marker = {
            "token": MARKER,
            "object_id": -1,
            "name": here,
            "state": DELETED,
            "symmetry": "none",
            "faces": 0,
            "created": now,
            "updated": now,
            "templates": "{}",
            "extra": "{}",
            "v": [0.0, 0.0],
        }
        self.client.upsert(self.objects_collection, [marker], timeout=self.timeout)
        log.info("a new template store, id %s (Milvus at %s, files in %s)", here, self.uri, self.files.root)
        return here

    def _directory_id(self) -> str | None:
        data = self.files.read(ID_FILE)
        return data.decode().strip() if data else None

    def _directory_problem(self) -> str | None:
        """Why this replica's shared directory is not the store's, or None when it is."""
        if self.store_id is None:
            return None
        try:
            here = self._directory_id()
        except OSError as e:
            here, why = None, f"({short(e)})"
        else:
            why = f"(its store id is {here})" if here else f"(it has no {ID_FILE})"
        if here == self.store_id:
            return None
        return (
            f"this replica's data directory {self.files.root} is not the one the store's replicas share "
            f"{why}, while the store (Milvus at {self.uri}) is {self.store_id}: mount the directory the other "
            "replicas write (meshes, local features) on every replica"
        )

    @staticmethod
    def _files_problem(missing: Mapping[int, list[str]], root: object) -> str | None:
        if not missing:
            return None
        shown = "; ".join(f"object {oid}: {', '.join(names)}" for oid, names in sorted(missing.items())[:3])
        more = f" and {len(missing) - 3} more objects" if len(missing) > 3 else ""
        return (
            f"files of live objects are missing from this replica's data directory {root} ({shown}{more}): "
            "it answers nothing until they are there (the directory the other replicas share, whole)"
        )


def counts_with_files(counts: Mapping[str, int], written: Mapping[str, Any]) -> str:
    """A record's template counts with the files its registration wrote, as the record stores them."""
    return json.dumps({**counts, FILES_KEY: written})
