"""The store under faults: a damaged `store.sqlite` is refused, a full disk leaves the previous state.

Real SQLite and FAISS files. The full disk is real SQLite behaviour (`PRAGMA max_page_count` at the
current size makes SQLite fail with SQLITE_FULL, "database or disk is full", as a full disk does); the
snapshot files' full disk is simulated (`os.fsync` raising ENOSPC)."""

from __future__ import annotations

import errno
import os
import sqlite3
from pathlib import Path

import numpy as np
import pytest

import index.store.snapshot_files
from index.store import Store, StoreError, TemplateSet, check_store

MODELS = {"rgb": (4, "fp-rgb"), "depth": (4, "fp-depth")}


def templates(centre: float, n: int = 5) -> TemplateSet:
    """n 4-d descriptors along a line near (centre, ..., centre)."""
    desc = np.full((n, 4), centre, np.float32)
    desc[:, 0] += np.arange(n) * 0.1
    return TemplateSet(np.zeros((n, 3)), desc)


def add(store: Store, name: str, centre: float) -> int:
    return store.add_object(name, "none", {m: templates(centre) for m in MODELS}).object_id


def _stored(tmp_path: Path) -> Path:
    """A closed store with objects a and b (5 templates each, per model)."""
    store = Store(tmp_path, MODELS)
    add(store, "a", 0.0)
    add(store, "b", 5.0)
    store.close()  # checkpoints the WAL: everything is in store.sqlite
    assert not (tmp_path / "store.sqlite-wal").exists()
    return tmp_path / "store.sqlite"


def _root_page(path: Path, table: str) -> tuple[int, int]:
    db = sqlite3.connect(path)
    (page,) = db.execute("SELECT rootpage FROM sqlite_master WHERE name = ?", (table,)).fetchone()
    (size,) = db.execute("PRAGMA page_size").fetchone()
    db.close()
    return page, size


def _damage(path: Path, how: str) -> None:
    data = bytearray(path.read_bytes())
    if how == "header":
        data[:100] = b"not a database, really" * 4 + b"...."
    elif how == "truncated":
        del data[len(data) // 2 :]
    elif how == "templates page":  # the b-tree page of the templates table: garbage
        page, size = _root_page(path, "templates")
        start = (page - 1) * size
        data[start : start + size] = np.random.default_rng(0).integers(0, 256, size, np.uint8).tobytes()
    elif how == "objects page":
        page, size = _root_page(path, "objects")
        start = (page - 1) * size
        data[start + 8 : start + size] = b"\xff" * (size - 8)  # keep the page type, garble the cells
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("how", ["header", "truncated", "templates page", "objects page"])
def test_a_damaged_sqlite_is_refused_in_one_line(tmp_path, how):
    path = _stored(tmp_path)
    _damage(path, how)
    with pytest.raises(StoreError) as refused:
        check_store(tmp_path)
    message = str(refused.value)
    assert "\n" not in message and str(path) in message
    assert "damaged" in message or "not a usable store" in message
    with pytest.raises(StoreError):  # the store itself refuses it too, whoever opens it
        Store(tmp_path, MODELS)


def test_check_store_passes_a_sound_or_missing_store(tmp_path):
    check_store(tmp_path / "nothing here")
    check_store(_stored(tmp_path).parent)


def _fill_the_disk(store: Store) -> None:
    (pages,) = store._db.execute("PRAGMA page_count").fetchone()
    store._db.execute(f"PRAGMA max_page_count = {pages}")


def test_a_full_disk_refuses_the_write_and_keeps_the_previous_state(tmp_path):
    store = Store(tmp_path, MODELS)
    a = add(store, "a", 0.0)
    before = store.snapshot
    _fill_the_disk(store)
    big = {m: templates(5.0, n=2000) for m in MODELS}  # needs new pages
    with pytest.raises(OSError) as full:
        store.add_object("b", "none", big, mesh=b"\0" * 100_000)
    assert full.value.errno == errno.ENOSPC and "disk full" in str(full.value)
    assert store.snapshot is before  # readers never saw b
    assert [m.name for m in store.search("rgb", np.full((1, 4), 5.0, np.float32), 3)[0]] == ["a"] * 3
    store._db.execute("PRAGMA max_page_count = 1073741823")  # space again: the next write works
    b = store.add_object("b", "none", big).object_id
    store.close()
    again = Store(tmp_path, MODELS)
    assert {r.name for r in again.snapshot.objects.values()} == {"a", "b"}
    assert again.snapshot.objects[a].templates == {"rgb": 5, "depth": 5}
    assert again.snapshot.objects[b].templates == {"rgb": 2000, "depth": 2000}
    assert again.missing() == {"rgb": [], "depth": []}


def test_a_full_disk_for_the_snapshots_keeps_the_commit_and_leaves_no_stale_tag(tmp_path, monkeypatch):
    store = Store(tmp_path, MODELS)
    add(store, "a", 0.0)

    def no_space(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(index.store.snapshot_files.os, "fsync", no_space)
    b = add(store, "b", 5.0)  # committed in SQLite; the snapshot files cannot be written
    store.flush()  # they are written after the write returns
    monkeypatch.undo()
    assert b in store.snapshot.objects
    assert not list(tmp_path.glob("*.tmp"))  # no half-written file takes up the space left
    assert not (tmp_path / "rgb.faiss.json").exists()  # the old snapshot is no longer tagged as current
    store.add_templates(b, "rgb", templates(9.0))  # a later write re-tags nothing stale
    store.remove_object(b)
    c = add(store, "c", 5.0)
    store.close()
    again = Store(tmp_path, MODELS)
    assert {r.name for r in again.snapshot.objects.values()} == {"a", "c"}
    for m, mi in again.snapshot.models.items():
        assert mi.index.ntotal == mi.size == 10, m
    (matches,) = again.search("rgb", np.full((1, 4), 5.0, np.float32), 1)
    assert matches[0].object_id == c and matches[0].distance == pytest.approx(0.0, abs=1e-5)
    assert os.path.getsize(tmp_path / "rgb.faiss") > 0


def test_a_full_disk_at_start_up_serves_from_sqlite(tmp_path, monkeypatch, caplog):
    """The snapshots are missing (or stale) and the disk is full: the store opens from SQLite and says so."""
    _stored(tmp_path)
    for f in tmp_path.glob("*.faiss*"):
        f.unlink()

    def no_space(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(index.store.snapshot_files.os, "fsync", no_space)
    with caplog.at_level("WARNING", logger="index.store"):
        store = Store(tmp_path, MODELS)
    assert "could not save the rgb index snapshot" in caplog.text and "serving from SQLite" in caplog.text
    assert {r.name for r in store.snapshot.objects.values()} == {"a", "b"}
    (matches,) = store.search("rgb", np.full((1, 4), 5.0, np.float32), 1)
    assert matches[0].name == "b" and matches[0].distance == pytest.approx(0.0, abs=1e-5)
    assert not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob("*.faiss.json"))
    monkeypatch.undo()
    c = add(store, "c", 9.0)  # space again: the next write saves the snapshots
    store.close()
    again = Store(tmp_path, MODELS)
    assert c in again.snapshot.objects and again.snapshot.models["rgb"].size == 15
