"""A full disk while the service saves: the write is refused with 507 and a JSON message (a server-side
condition, not the client's fault, and worth telling apart from a bug's 500), the previous state
survives, the service keeps answering from it, and works again once there is space.

The app runs in-process with its lifespan (real store, renderer, models). The full disk is SQLite's
own: `PRAGMA max_page_count` at the current size makes SQLite fail with SQLITE_FULL ("database or disk
is full") as a full disk does; writing the snapshot files is made to fail with ENOSPC (`os.fsync`)."""

from __future__ import annotations

import errno
import json
import sqlite3
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import faiss
import pytest
from fastapi.testclient import TestClient
from service_helpers import patch_files, register, service_settings, wait_ready

import index.store.snapshot_files
from service.main import create_app

QUERY = {"files": patch_files()["rgb"], "data": {"k": "100"}}


@contextmanager
def full_disk(client: TestClient, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    store = client.app.state.posedesc.store

    def no_space(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    with store._write:
        (pages,) = store._db.execute("PRAGMA page_count").fetchone()
        store._db.execute(f"PRAGMA max_page_count = {pages}")
    monkeypatch.setattr(index.store.snapshot_files.os, "fsync", no_space)
    try:
        yield
    finally:
        store.flush()  # the snapshot files of what was written meanwhile, written after each write returned
        monkeypatch.undo()
        with store._write:
            store._db.execute("PRAGMA max_page_count = 1073741823")


def found(client: TestClient) -> set[int]:
    r = client.post("/recognize", **QUERY)
    assert r.status_code == 200, r.text
    return {m["object_id"] for m in r.json()["matches"]}


def snapshots_match_sqlite(data_dir: Path) -> None:
    db = sqlite3.connect(data_dir / "store.sqlite")
    (generation,) = db.execute("SELECT value FROM meta WHERE key = 'generation'").fetchone()
    counts = dict(db.execute("SELECT model, COUNT(*) FROM templates GROUP BY model").fetchall())
    db.close()
    for m in ("rgb", "depth", "rgbd"):
        tag = json.loads((data_dir / f"{m}.faiss.json").read_text())
        assert tag["generation"] == int(generation) and tag["ntotal"] == counts.get(m, 0), m
        assert faiss.read_index(str(data_dir / f"{m}.faiss")).ntotal == counts.get(m, 0), m


def test_a_full_disk_refuses_writes_and_keeps_serving(
    tmp_path, posedesc_models, l_shape, t_shape, monkeypatch
):
    settings = service_settings(tmp_path / "data", posedesc_models, level=1)
    with TestClient(create_app(settings)) as c:
        wait_ready(c)
        l_id = register(c, l_shape, "L")["object_id"]
        objects = c.get("/objects").json()
        assert found(c) == {l_id}

        with full_disk(c, monkeypatch):
            r = c.post(
                "/objects", files={"mesh": ("T.ply", t_shape.export(file_type="ply"))}, data={"name": "T"}
            )
            assert r.status_code == 507, r.text
            assert r.json() == {
                "detail": "the server's disk is full: nothing was changed; retry once space is freed"
            }
            assert c.get("/objects").json() == objects  # nothing half-added
            assert found(c) == {l_id}
            assert c.get("/readyz").status_code == 200

        t_id = register(c, t_shape, "T")["object_id"]  # space again: writes work
        assert found(c) == {l_id, t_id}

        with full_disk(c, monkeypatch):  # a delete needs no new pages: SQLite commits it, the snapshots fail
            assert c.delete(f"/objects/{t_id}").status_code == 204
            assert found(c) == {l_id}
            c.app.state.posedesc.store.flush()  # the snapshot files are written after the delete returns
            assert not list(settings.data_dir.glob("*.tmp"))  # no half-written snapshot left taking space

    with TestClient(create_app(settings)) as c:  # a restart: SQLite's state, the stale snapshots rebuilt
        wait_ready(c)
        assert c.get("/objects").json() == objects
        assert found(c) == {l_id}
    snapshots_match_sqlite(settings.data_dir)


def test_a_full_disk_at_start_up_still_serves(tmp_path, posedesc_models, l_shape, monkeypatch, caplog):
    """Snapshots to rebuild and no space to save them: the service starts from SQLite and says so."""
    settings = service_settings(tmp_path / "data", posedesc_models, level=1)
    with TestClient(create_app(settings)) as c:
        wait_ready(c)
        l_id = register(c, l_shape, "L")["object_id"]
    for f in settings.data_dir.glob("*.faiss*"):
        f.unlink()

    def no_space(fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(index.store.snapshot_files.os, "fsync", no_space)
    with caplog.at_level("WARNING"), TestClient(create_app(settings)) as c:
        assert wait_ready(c)["objects"] == 1
        assert found(c) == {l_id}
    assert "serving from SQLite" in caplog.text
    assert not list(settings.data_dir.glob("*.tmp"))
