"""The embedded store's local features on disk, memory-mapped (`index.store.embedded`): one `.npy` file per
object and model, `local/<model>-<fingerprint>/<object id>.npy`, its rows (L, W) float16 (each upright
viewpoint's features, silhouette and relief: `index.features.local.StoredLocal`) in the order of the object's
template ids.

Why: the local features are nine tenths of what an object costs (301 viewpoints x 6,656 float16 = 4 MB a
model), and a query reads those of ~200 candidate viewpoints; held in the heap they made a store of 1,000
objects ~9 GB. Mapped, they are page cache: read when a query needs them, dropped by the kernel when memory
is short, shared by every process serving the same files (`docs/results/bench-memory.json`).

SQLite stays the truth: a file is only a copy, made again from SQLite whenever it is missing or does not
have the shape SQLite says; files of objects SQLite does not hold (a registration rolled back, a removal
interrupted) and of a model's earlier fingerprints are removed when the store opens (`sweep`). A file holding
the very bytes another model's file of the object holds (the RGB-D model takes the rgb model's templates,
`index.templates.register.template_twins`) is a hard link to it: one file on disk, one mapping in memory. In SQLite,
such a twin's rows of a registration hold no copy either, only a pointer to the rows they equal (`marker`;
copied before those rows are deleted: `keep_twins`)."""

from __future__ import annotations

import io
import logging
import os
import shutil
import sqlite3
import uuid
import weakref
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from index.store.records import StoreError, local_key
from index.store.snapshot_files import write_atomic

log = logging.getLogger("index.store")

LOCAL_DIR = "local"


class LocalFiles:
    """The local-feature files of a data dir for these models (name -> fingerprint)."""

    def __init__(self, data_dir: Path, fingerprints: Mapping[str, str]):
        self.root = Path(data_dir) / LOCAL_DIR
        self.dirs = {m: self.root / f"{m}-{fp}" for m, fp in fingerprints.items()}
        # one mapping per file (inode), however many models map it, for as long as any row of it is used;
        # keyed by its size and time too: a removed file's inode number may come again for a new file
        # while the old mapping is still in use (a snapshot a query holds, a pipeline's cached table)
        self._maps: weakref.WeakValueDictionary[tuple[int, ...], np.ndarray] = weakref.WeakValueDictionary()

    def path(self, model: str, object_id: int) -> Path:
        return self.dirs[model] / f"{int(object_id)}.npy"

    def read(self, model: str, object_id: int, shape: tuple[int, int]) -> np.ndarray | None:
        """The object's rows for `model`, mapped, when its file holds `shape` float16; else None."""
        path = self.path(model, object_id)
        try:
            return self._map(path, shape)
        except (OSError, ValueError) as e:
            if path.exists():
                log.warning("%s does not hold %s local features (%s): made again from SQLite", path, shape, e)
            return None

    def write(self, model: str, object_id: int, rows: np.ndarray) -> np.ndarray:
        """Writes the object's rows for `model` (a link to another model's file of it when that holds the
        same bytes) and returns them mapped; on a failure to write (a full disk), the rows themselves:
        the file is made again from SQLite at the next start."""
        rows = np.ascontiguousarray(rows, np.float16)
        path = self.path(model, object_id)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            if (twin := self._twin(model, object_id, rows)) is not None:
                tmp = path.with_name(f"{path.name}.{uuid.uuid4().hex}.tmp")
                os.link(twin, tmp)
                os.replace(tmp, path)
            else:
                write_atomic(path, _npy(rows))
            return self._map(path, rows.shape)
        except (OSError, ValueError) as e:
            log.warning("could not write %s (%s): its local features stay in memory", path, e)
            path.unlink(missing_ok=True)
            return rows

    def remove(self, object_id: int, models: list[str] | None = None) -> None:
        """The object's files (of `models`, default all); mappings in use stay valid."""
        for m in self.dirs if models is None else models:
            path = self.path(m, object_id)
            try:
                self._maps.pop(_identity(path), None)
            except OSError:
                continue
            path.unlink(missing_ok=True)

    def sweep(self, object_ids: set[int]) -> None:
        """Removes the files of objects not in `object_ids`, temporary files, and the folders of these
        models' other fingerprints (their templates were dropped: `EmbeddedStore._forget_changed_models`)."""
        if not self.root.is_dir():
            return
        current = set(self.dirs.values())
        for d in self.root.iterdir():
            if d not in current and any(d.name.startswith(f"{m}-") for m in self.dirs):
                shutil.rmtree(d, ignore_errors=True)
        for d in self.dirs.values():
            if not d.is_dir():
                continue
            for p in d.iterdir():
                stem = p.name.split(".", 1)[0]
                if p.suffix != ".npy" or not stem.isdigit() or int(stem) not in object_ids:
                    p.unlink(missing_ok=True)

    def load(self, db: sqlite3.Connection, model: str) -> dict[tuple[int, float, float], np.ndarray]:
        """`model`'s local features by viewpoint (`index.store.records.local_key`) in the store `db`: each
        object's rows mapped from its file, the file made from SQLite's rows when missing or not of
        their shape (rows of several widths, from older layouts, stay in memory as they are)."""
        by_object: dict[int, list[tuple[float, float, int]]] = {}
        sizes: dict[str, dict[tuple, int]] = {}  # of the models a twin's rows point to
        for oid, az, el, ip, size, pointer in db.execute(
            "SELECT object_id, azimuth, elevation, inplane, length(local), "
            "CASE WHEN length(local) % 2 = 1 THEN local END FROM templates "
            "WHERE model = ? AND local IS NOT NULL ORDER BY id",
            (model,),
        ):
            if pointer is not None:  # a twin's row: the size of the row it points to
                src = marked(pointer)
                if src not in sizes:
                    sizes[src] = {
                        tuple(r[:4]): int(r[4])
                        for r in db.execute(
                            "SELECT object_id, azimuth, elevation, inplane, length(local) FROM templates "
                            "WHERE model = ? AND local IS NOT NULL",
                            (src,),
                        )
                    }
                size = sizes[src].get((oid, az, el, ip), 1)  # none: a damaged store, refused below
            by_object.setdefault(int(oid), []).append((az, el, int(size)))
        local: dict[tuple[int, float, float], np.ndarray] = {}
        for oid, rows in by_object.items():
            width = rows[0][2] // 2
            if any(size != 2 * width for *_, size in rows):  # rows of several layouts: as they are, in memory
                blobs = [np.frombuffer(b, np.float16) for b in _blobs(db, model, oid)]
            else:
                mapped = self.read(model, oid, (len(rows), width))
                if mapped is None:
                    stacked = np.stack([np.frombuffer(b, np.float16) for b in _blobs(db, model, oid)])
                    mapped = self.write(model, oid, stacked)
                blobs = list(mapped)
            for (az, el, _), f in zip(rows, blobs, strict=True):
                local[local_key(oid, az, el)] = f
        return local

    def _twin(self, model: str, object_id: int, rows: np.ndarray) -> Path | None:
        for m in self.dirs:
            other = self.path(m, object_id)
            if m == model or not other.is_file():
                continue
            mapped = self.read(m, object_id, rows.shape)
            if mapped is not None and np.array_equal(mapped.view(np.uint16), rows.view(np.uint16)):
                return other
        return None

    def _map(self, path: Path, shape: tuple[int, ...]) -> np.ndarray:
        key = _identity(path)
        if (hit := self._maps.get(key)) is None:
            mm = np.load(path, mmap_mode="r", allow_pickle=False)
            # a plain array over the mapping: its rows are plain views, lighter than np.memmap's
            hit = self._maps[key] = np.asarray(mm)
        if hit.dtype != np.float16 or hit.shape != tuple(shape):
            raise ValueError(f"holds {hit.shape} {hit.dtype}")
        return hit


def _identity(path: Path) -> tuple[int, ...]:
    """What tells a file apart from every other, its hard links aside (they share an inode)."""
    st = path.stat()
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def _blobs(db: sqlite3.Connection, model: str, object_id: int) -> list[bytes]:
    """The object's local rows of `model` in template id order, a twin's taken where they point."""
    out = []
    for az, el, ip, blob in db.execute(
        "SELECT azimuth, elevation, inplane, local FROM templates "
        "WHERE model = ? AND object_id = ? AND local IS NOT NULL ORDER BY id",
        (model, object_id),
    ).fetchall():
        if len(blob) % 2:
            row = db.execute(
                "SELECT local FROM templates WHERE model = ? AND object_id = ? AND azimuth = ? "
                "AND elevation = ? AND inplane = ?",
                (marked(blob), object_id, az, el, ip),
            ).fetchone()
            if row is None or len(row[0]) % 2:
                raise StoreError(
                    f"object {object_id}'s {model} local features point to "
                    f"{marked(blob)}'s, which are missing; restore the store from a backup"
                )
            blob = row[0]
        out.append(blob)
    return out


def keep_twins(db: sqlite3.Connection, model: str) -> None:
    """Before `model`'s rows are deleted: the rows of other models that point to its local features
    (`marker`) take a copy of them."""
    db.execute(
        "UPDATE templates SET local = (SELECT s.local FROM templates s WHERE s.model = ? "
        "AND s.object_id = templates.object_id AND s.azimuth = templates.azimuth "
        "AND s.elevation = templates.elevation AND s.inplane = templates.inplane) "
        "WHERE model != ? AND local = ?",
        (model, model, marker(model)),
    )


def marker(src: str) -> bytes:
    """A twin's local blob: "the same as model `src`'s row of this template". Of odd length: a row of
    float16 values never is."""
    b = b"=" + src.encode()
    return b if len(b) % 2 else b + b" "


def marked(blob: bytes) -> str:
    return blob[1:].decode().strip()


def _npy(rows: np.ndarray) -> bytes:
    """`rows` as the bytes of an .npy file."""
    buf = io.BytesIO()
    np.save(buf, rows, allow_pickle=False)
    return buf.getvalue()
