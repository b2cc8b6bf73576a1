"""The embedded store's index snapshot files: `<model>.faiss` and its tag `<model>.faiss.json`
(generation, ntotal, index kind, sha256), each written through a temporary file and an atomic rename. A
snapshot is used only when its tag matches SQLite's generation and its bytes their checksum; otherwise
(missing, stale, corrupt) the caller rebuilds the index from SQLite (`build_index`)."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import uuid
from pathlib import Path

import faiss
import numpy as np

log = logging.getLogger("index.store")

INDEX_KINDS = ("auto", "flat", "ivf")

#: "auto": exact below this many templates, IVF from it, unless the caller says otherwise (`ivf_min`; the
#: service passes its setting `ivf_min_templates`, where the measurement behind the number is kept)
AUTO_IVF_MIN = 50_000


def paths(data_dir: Path, model: str) -> tuple[Path, Path]:
    p = data_dir / f"{model}.faiss"
    return p, p.with_name(p.name + ".json")


def read_snapshot(
    data_dir: Path, model: str, generation: int, ntotal: int, dim: int, kind: str
) -> tuple[faiss.Index, dict] | None:
    """The snapshot of `model` and its tag when both match (generation, size, dim, kind), else None."""
    path, tag_path = paths(data_dir, model)
    if not path.is_file() or not tag_path.is_file():
        log.info("%s: no index snapshot, building it from SQLite", model)
        return None
    try:
        tag = json.loads(tag_path.read_text())
        data = path.read_bytes()
        if tag.get("generation") != generation:
            log.info("%s: index snapshot is stale, building it from SQLite", model)
            return None
        if tag.get("kind") != kind:  # written by a store opened with another INDEX_KIND: not damage
            log.info(
                "%s: index snapshot is a %s index, %s wanted: building it from SQLite",
                model,
                tag.get("kind"),
                kind,
            )
            return None
        if tag.get("sha256") != hashlib.sha256(data).hexdigest():
            raise ValueError("checksum mismatch")
        index = faiss.deserialize_index(np.frombuffer(data, np.uint8))
        if index.ntotal != ntotal or index.d != dim:
            raise ValueError(f"holds {index.ntotal} x {index.d}, SQLite {ntotal} x {dim}")
    except Exception as e:
        log.warning("%s: index snapshot %s is corrupt (%s): building it from SQLite", model, path, e)
        return None
    return index, tag


def read_tag(data_dir: Path, model: str) -> dict | None:
    """`model`'s snapshot tag, or None when there is none or it cannot be read."""
    try:
        tag = json.loads(paths(data_dir, model)[1].read_text())
    except (OSError, ValueError):
        return None
    return tag if isinstance(tag, dict) else None


def ivf_from(kind: str, n: int, nlist: int, ivf_min: int = AUTO_IVF_MIN) -> bool:
    """Whether a `kind` index of n templates is IVF: "ivf" once there are enough to train it (39 per
    list), "auto" from `ivf_min` (and enough to train), "flat" never."""
    enough = n >= 39 * nlist
    if kind == "ivf":
        return enough
    return kind == "auto" and enough and n >= ivf_min


def build_index(
    desc: np.ndarray, ids: np.ndarray, kind: str, nlist: int, nprobe: int, ivf_min: int = AUTO_IVF_MIN
) -> faiss.Index:
    """ "flat": exact, `IndexIDMap2(IndexFlatL2)`; "ivf": `IndexIVFFlat`, trained on these descriptors,
    exact (flat) until there are enough to train it (`ivf_from`); "auto": exact for a small collection,
    IVF for a large one. HNSW is not offered: it cannot remove ids."""
    dim = desc.shape[1]
    if ivf_from(kind, len(ids), nlist, ivf_min):
        index: faiss.Index = faiss.IndexIVFFlat(faiss.IndexFlatL2(dim), dim, nlist)
        index.train(desc)
    else:
        index = faiss.IndexIDMap2(faiss.IndexFlatL2(dim))
    tune(index, nprobe)
    if len(ids):
        index.add_with_ids(desc, ids)
    return index


def grown(index: faiss.Index, kind: str, nlist: int, nprobe: int, ivf_min: int = AUTO_IVF_MIN) -> faiss.Index:
    """`index` after a write: an exact one that has grown to where `kind` wants IVF is built again as
    IVF from its own vectors and ids (once: IVF stays IVF, its lists trained on what it held then);
    otherwise `index` itself."""
    if faiss.try_extract_index_ivf(index) is not None or not ivf_from(kind, index.ntotal, nlist, ivf_min):
        return index
    ids = faiss.vector_to_array(index.id_map).astype(np.int64)  # type: ignore[attr-defined]  # IndexIDMap2
    desc = faiss.downcast_index(index.index).reconstruct_n(0, index.ntotal)  # type: ignore[attr-defined]
    return build_index(np.ascontiguousarray(desc, np.float32), ids, kind, nlist, nprobe, ivf_min)


def tune(index: faiss.Index, nprobe: int) -> None:
    if (ivf := faiss.try_extract_index_ivf(index)) is not None:
        ivf.nprobe = nprobe


def save_snapshot(data_dir: Path, model: str, index: faiss.Index, generation: int, kind: str) -> dict:
    """Writes the snapshot file then its tag; returns the tag."""
    path, tag_path = paths(data_dir, model)
    data = faiss.serialize_index(index).data  # no copy into bytes: hashed and written as it is
    tag = {
        "generation": generation,
        "ntotal": int(index.ntotal),
        "kind": kind,
        "sha256": hashlib.sha256(data).hexdigest(),
    }
    write_atomic(path, data)
    write_atomic(tag_path, json.dumps(tag).encode())
    return tag


def write_atomic(path: Path, content: bytes | memoryview) -> None:
    """`content` into `path` whole or not at all (a temporary file, fsync, rename); the temporary file's
    name is unique, so writers in several processes (replicas on a shared directory) never share one."""
    tmp = path.with_name(f"{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(content)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError:
        tmp.unlink(missing_ok=True)  # a half-written file only takes the space a full disk lacks
        raise
