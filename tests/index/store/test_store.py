"""The embedded template store's own behaviour: real FAISS and SQLite files in a temporary data dir,
hand-made descriptors. What every backend does: test_store_contract.py."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import threading
from pathlib import Path

import faiss
import numpy as np
import pytest

from index.store import Store, StoreError, TemplateSet

MODELS = {"rgb": (4, "fp-rgb"), "depth": (4, "fp-depth")}
ROOT = Path(__file__).resolve().parents[3]


def templates(centre: float, n: int = 5, dim: int = 4) -> TemplateSet:
    """n descriptors along a line near (centre, ..., centre); pose azimuth = 10 * i."""
    desc = np.full((n, dim), centre, np.float32)
    desc[:, 0] += np.arange(n) * 0.1
    poses = np.stack([np.arange(n) * 10.0, np.full(n, 30.0), np.zeros(n)], axis=1)
    return TemplateSet(poses, desc)


def add(store: Store, name: str, centre: float) -> int:
    return store.add_object(name, "none", {m: templates(centre) for m in MODELS}).object_id


def test_reopen_keeps_state_and_uses_the_snapshot(tmp_path, caplog):
    store = Store(tmp_path, MODELS)
    add(store, "a", 0.0)
    b = add(store, "b", 5.0)
    store.remove_object(b)
    gen = store.snapshot.generation
    store.close()
    tag = json.loads((tmp_path / "rgb.faiss.json").read_text())
    assert tag["generation"] == gen and tag["ntotal"] == 5
    with caplog.at_level("INFO", logger="index.store"):
        again = Store(tmp_path, MODELS)
    assert "building" not in caplog.text  # loaded from the snapshots, not rebuilt
    assert [r.name for r in again.snapshot.objects.values()] == ["a"]
    assert again.snapshot.generation == gen
    assert {m.name for m in again.search("rgb", np.zeros((1, 4), np.float32), 10)[0]} == {"a"}


@pytest.mark.parametrize("damage", ["missing", "stale", "corrupt", "wrong_size"])
def test_damaged_snapshot_is_rebuilt_from_sqlite(tmp_path, caplog, damage):
    store = Store(tmp_path, MODELS)
    add(store, "a", 0.0)
    add(store, "b", 5.0)
    store.close()
    path, tag_path = tmp_path / "rgb.faiss", tmp_path / "rgb.faiss.json"
    if damage == "missing":
        path.unlink()
    elif damage == "stale":
        tag = json.loads(tag_path.read_text())
        tag["generation"] -= 1
        tag_path.write_text(json.dumps(tag))
    elif damage == "corrupt":  # bytes flipped, tag untouched: the checksum catches it
        data = bytearray(path.read_bytes())
        data[len(data) // 2] ^= 0xFF
        path.write_bytes(bytes(data))
    else:  # a well-formed index of the right generation that does not match SQLite
        small = faiss.IndexIDMap2(faiss.IndexFlatL2(4))
        small.add_with_ids(np.zeros((1, 4), np.float32), np.array([1], np.int64))
        data = faiss.serialize_index(small).tobytes()
        tag = json.loads(tag_path.read_text())
        tag["sha256"] = hashlib.sha256(data).hexdigest()
        path.write_bytes(data)
        tag_path.write_text(json.dumps(tag))
    with caplog.at_level("INFO", logger="index.store"):
        again = Store(tmp_path, MODELS)
    assert "building it from SQLite" in caplog.text
    mi = again.snapshot.models["rgb"]
    assert mi.index.ntotal == 10 and mi.size == 10
    (matches,) = again.search("rgb", np.full((1, 4), 5.0, np.float32), 1)
    assert matches[0].name == "b" and matches[0].distance == pytest.approx(0.0, abs=1e-5)


def test_a_snapshot_of_another_index_kind_is_rebuilt_without_a_warning(tmp_path, caplog):
    """A store opened with another INDEX_KIND (the bench's exact baseline beside the service's own) finds a
    sound snapshot of the other kind: rebuilt, said at INFO, not reported as damage."""
    store = Store(tmp_path, MODELS, kind="flat")
    add(store, "a", 0.0)
    store.close()
    with caplog.at_level("INFO", logger="index.store"):
        again = Store(tmp_path, MODELS, kind="ivf")
    assert "is a flat index, ivf wanted: building it from SQLite" in caplog.text
    assert not [r for r in caplog.records if r.levelname == "WARNING"], caplog.text
    assert again.snapshot.models["rgb"].index.ntotal == 5


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    store = Store(tmp_path, MODELS)
    add(store, "a", 0.0)

    def boom(*args, **kwargs):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(store, "_next", boom)
    with pytest.raises(RuntimeError):
        add(store, "b", 5.0)
    monkeypatch.undo()
    assert [r.name for r in store.snapshot.objects.values()] == ["a"]
    store.close()
    again = Store(tmp_path, MODELS)
    assert [r.name for r in again.snapshot.objects.values()] == ["a"]
    assert again.snapshot.models["rgb"].size == 5


def test_crash_in_the_middle_of_a_registration(tmp_path):
    """A process killed after writing an object's rows but before committing: the object is absent."""
    store = Store(tmp_path, MODELS)
    add(store, "a", 0.0)
    store.close()
    script = f"""
import os, sys
sys.path.insert(0, {str(ROOT)!r})
sys.path.insert(0, {str(Path(__file__).parent)!r})
from index.store import Store
from test_store import MODELS, templates
store = Store({str(tmp_path)!r}, MODELS)
def die(cur, **kw):
    n = cur.execute("SELECT COUNT(*) FROM templates").fetchone()[0]
    print(n, flush=True)
    os._exit(3)
store._next = die
store.add_object("b", "none", {{m: templates(5.0) for m in MODELS}})
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 3, done.stderr
    assert int(done.stdout) == 20  # b's rows were written inside the transaction...
    again = Store(tmp_path, MODELS)  # ...and are gone after the crash
    assert [r.name for r in again.snapshot.objects.values()] == ["a"]
    assert {m: mi.size for m, mi in again.snapshot.models.items()} == {"rgb": 5, "depth": 5}
    assert again.missing() == {"rgb": [], "depth": []}


def test_bad_inputs(tmp_path):
    with pytest.raises(StoreError, match="index kind"):
        Store(tmp_path, MODELS, kind="hnsw")
    store = Store(tmp_path, MODELS)
    with pytest.raises(ValueError, match=r"expected \(N, 4\)"):
        store.add_object("x", "none", {"rgb": templates(0.0, dim=3)})
    with pytest.raises(KeyError):
        store.add_object("x", "none", {"rgbd": templates(0.0)})
    bad = templates(0.0)
    bad.descriptors[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        store.add_object("x", "none", {"rgb": bad})
    assert store.snapshot.objects == {}
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "store.sqlite").write_bytes(b"this is not a database" * 100)
    with pytest.raises(StoreError, match="not a usable store"):
        Store(tmp_path / "junk", MODELS)


def test_ivf_kind(tmp_path):
    store = Store(tmp_path, {"rgb": (4, "fp")}, kind="ivf", nlist=2, nprobe=2)
    rng = np.random.default_rng(0)
    for i in range(20):
        desc = rng.normal(i, 0.1, (10, 4)).astype(np.float32)
        store.add_object(f"o{i}", "none", {"rgb": TemplateSet(np.zeros((10, 3)), desc)})
        is_ivf = faiss.try_extract_index_ivf(store.snapshot.models["rgb"].index) is not None
        assert is_ivf == (10 * (i + 1) >= 39 * 2), i  # exact until there are enough to train it
    store.close()
    (tmp_path / "rgb.faiss").unlink()  # rebuilt from SQLite: trained on every template
    again = Store(tmp_path, {"rgb": (4, "fp")}, kind="ivf", nlist=2, nprobe=2)
    assert faiss.try_extract_index_ivf(again.snapshot.models["rgb"].index) is not None
    (matches,) = again.search("rgb", np.full((1, 4), 7.0, np.float32), 3)
    assert {m.name for m in matches} == {"o7"}
    assert again.remove_object(matches[0].object_id)
    (matches,) = again.search("rgb", np.full((1, 4), 7.0, np.float32), 3)
    assert "o7" not in {m.name for m in matches}


def test_auto_kind_is_exact_while_small_and_turns_ivf_at_the_write_that_makes_it_large(tmp_path, caplog):
    store = Store(tmp_path, {"rgb": (4, "fp")}, nlist=2, nprobe=2, ivf_min=150)  # "auto", the default
    rng = np.random.default_rng(0)
    ids = []
    for i in range(20):
        desc = rng.normal(i, 0.1, (10, 4)).astype(np.float32)
        ids.append(store.add_object(f"o{i}", "none", {"rgb": TemplateSet(np.zeros((10, 3)), desc)}).object_id)
        is_ivf = faiss.try_extract_index_ivf(store.snapshot.models["rgb"].index) is not None
        assert is_ivf == (10 * (i + 1) >= 150), i  # exact below the threshold, IVF from the write reaching it
    (matches,) = store.search("rgb", np.full((1, 4), 3.0, np.float32), 3)
    assert {m.name for m in matches} == {"o3"}  # objects added before the switch are found
    (matches,) = store.search("rgb", np.full((1, 4), 19.0, np.float32), 3)
    assert {m.name for m in matches} == {"o19"}  # and after it
    assert store.remove_object(ids[19])
    store.close()
    with caplog.at_level("INFO", logger="index.store"):
        again = Store(tmp_path, {"rgb": (4, "fp")}, nlist=2, nprobe=2)
    assert "building" not in caplog.text  # the IVF snapshot was saved and is used
    mi = again.snapshot.models["rgb"]
    assert faiss.try_extract_index_ivf(mi.index) is not None and mi.index.ntotal == mi.size == 190
    (matches,) = again.search("rgb", np.full((1, 4), 19.0, np.float32), 3)
    assert "o19" not in {m.name for m in matches}


def test_readers_never_see_half_an_object(tmp_path):
    store = Store(tmp_path, MODELS)
    stop = threading.Event()
    errors: list[str] = []

    def reader():
        q = np.zeros((1, 4), np.float32)
        while not stop.is_set():
            snap = store.snapshot
            for m, mi in snap.models.items():
                if mi.index.ntotal != mi.size:
                    errors.append(f"{m}: index {mi.index.ntotal} != metadata {mi.size}")
                for oid, rec in snap.objects.items():
                    if int((mi.object_ids == oid).sum()) != rec.templates[m]:
                        errors.append(f"{m}: object {oid} partly present")
            for match in snap.search("rgb", q, 50)[0]:
                if match.object_id not in snap.objects:
                    errors.append(f"match of unknown object {match.object_id}")

    threads = [threading.Thread(target=reader) for _ in range(2)]
    for t in threads:
        t.start()
    ids = []
    for i in range(30):
        ids.append(add(store, f"o{i}", float(i % 3)))
        if i % 3 == 2:
            store.remove_object(ids.pop(0))
    stop.set()
    for t in threads:
        t.join()
    assert errors == []
    assert len(store.snapshot.objects) == 20


def test_a_store_from_before_local_features_opens(tmp_path):
    import sqlite3

    from index.store import SCHEMA

    db = sqlite3.connect(tmp_path / "store.sqlite")
    db.executescript(
        SCHEMA.replace("    descriptor BLOB NOT NULL,\n    local BLOB\n", "    descriptor BLOB NOT NULL\n")
    )
    db.close()
    store = Store(tmp_path, MODELS)
    oid = add(store, "a", 1.0)
    assert oid in store.snapshot.objects and not store.snapshot.models["rgb"].local
    store.close()
