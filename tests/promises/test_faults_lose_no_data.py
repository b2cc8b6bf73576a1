"""`posedesc serve` under faults: SIGKILL in the middle of a registration, damaged index snapshots, a
damaged `store.sqlite`. After a restart the store is consistent (each object wholly present or wholly
absent, for every model, in SQLite, in FAISS and in the answers), or the service refuses to start
with one line and leaves the damaged file as it was."""

from __future__ import annotations

import hashlib
import json
import shutil
import sqlite3
import subprocess
import time
from pathlib import Path

import faiss
import httpx
import numpy as np
import pytest
from service_helpers import ROOT, Server, expected_templates, free_port, patch_files, serve_command

from index.templates.register import TemplateConfig, template_views

pytestmark = pytest.mark.xdist_group("faults")  # the module's fixture made once, on one worker

ENV = {"POSEDESC_LEVEL": "1", "POSEDESC_SYNC_SECONDS": "0"}  # short registrations, all answered 202
VIEWS = len(template_views("none", TemplateConfig(level=1)))  # 16 templates per object and model
MODELS = ("rgb", "depth", "rgbd")
PATCHES = patch_files()  # k = 100: more than all the templates of these tests, so every one comes back


def post_mesh(c: httpx.Client, mesh, name: str) -> str:
    r = c.post("/objects", files={"mesh": (f"{name}.ply", mesh.export(file_type="ply"))}, data={"name": name})
    assert r.status_code == 202, r.text
    return r.json()["job_id"]


def wait_job(c: httpx.Client, job_id: str, timeout: float = 60.0) -> dict:
    end = time.monotonic() + timeout
    while (job := c.get(f"/jobs/{job_id}").json())["status"] == "running":
        assert time.monotonic() < end, "registration did not finish"
        time.sleep(0.05)
    assert job["status"] == "done", job
    return job


def answers(c: httpx.Client) -> dict[str, list[dict]]:
    out = {}
    for model, files in PATCHES.items():
        r = c.post("/recognize", files=files, data={"k": "100"})
        assert r.status_code == 200, r.text
        out[model] = r.json()["matches"]
    return out


def check_consistent(server: Server, data_dir: Path) -> dict[int, str]:
    """Asserts that the API, SQLite and the FAISS snapshots agree, every object wholly present for
    every model; returns the objects (id: name)."""
    with httpx.Client(base_url=server.url, timeout=60) as c:
        listed = {o["object_id"]: o["name"] for o in c.get("/objects").json()}
        ready = c.get("/readyz").json()
        found = {model: {m["object_id"] for m in matches} for model, matches in answers(c).items()}
    db = sqlite3.connect(f"file:{data_dir / 'store.sqlite'}?mode=ro", uri=True)
    objects = dict(db.execute("SELECT id, name FROM objects").fetchall())
    counts = {
        (o, m): n for o, m, n in db.execute("SELECT object_id, model, COUNT(*) FROM templates GROUP BY 1, 2")
    }
    (generation,) = db.execute("SELECT value FROM meta WHERE key = 'generation'").fetchone()
    db.close()
    assert listed == objects
    per = {m: expected_templates(server.models, m, VIEWS) for m in MODELS}
    assert counts == {(o, m): per[m] for o in objects for m in MODELS}  # whole objects, no orphan templates
    for m in MODELS:
        tag = json.loads((data_dir / f"{m}.faiss.json").read_text())
        index = faiss.read_index(str(data_dir / f"{m}.faiss"))
        assert index.ntotal == tag["ntotal"] == ready["templates"][m] == per[m] * len(objects), m
        assert tag["generation"] == int(generation), m
        assert found[m] == set(objects), m  # every object is found, and no other
    return objects


@pytest.mark.slow
def test_sigkill_during_a_registration_leaves_the_object_wholly_present_or_absent(
    tmp_path, posedesc_models, l_shape, t_shape
):
    data_dir = tmp_path / "data"
    server = Server(data_dir, posedesc_models, ENV)
    try:
        server.wait_ready()
        with httpx.Client(base_url=server.url, timeout=60) as c:
            keep = wait_job(c, post_mesh(c, l_shape, "L"))["object_id"]
            seconds = c.get(f"/jobs/{post_mesh(c, t_shape, 'probe')}").json()  # times one registration
        with httpx.Client(base_url=server.url, timeout=60) as c:
            probe = wait_job(c, seconds["job_id"])["result"]
            assert c.delete(f"/objects/{probe['object_id']}").status_code == 204
        took = probe["seconds"]
        present: dict[str, bool] = {}
        # SIGKILL at several points of a registration: before the render is done, near the end (the
        # commit and the snapshot files), just after, and once the job said it was done.
        for when in (0.0, 0.6, 0.95, 1.05, "done"):
            name = f"T-{when}"
            with httpx.Client(base_url=server.url, timeout=60) as c:
                job_id = post_mesh(c, t_shape, name)
                assert c.get(f"/jobs/{job_id}").json()["status"] == "running"
                if when == "done":
                    wait_job(c, job_id)
                else:
                    time.sleep(float(when) * took)
            server.kill()
            server = Server(data_dir, posedesc_models, ENV)
            server.wait_ready()
            objects = check_consistent(server, data_dir)
            assert objects[keep] == "L"
            present[name] = name in objects.values()
        assert present["T-0.0"] is False  # killed long before its templates were made
        assert present["T-done"] is True  # a registration that was answered survives a SIGKILL
    finally:
        server.kill()
    assert "Traceback" not in server.log.read_text()


# two registrations and a server restart: ~5 s
@pytest.mark.slow
def test_damaged_snapshots_are_rebuilt_from_sqlite(tmp_path, posedesc_models, l_shape, t_shape):
    data_dir = tmp_path / "data"
    with Server(data_dir, posedesc_models, ENV) as server:
        server.wait_ready()
        with httpx.Client(base_url=server.url, timeout=60) as c:
            wait_job(c, post_mesh(c, l_shape, "L"))
            wait_job(c, post_mesh(c, t_shape, "T"))
            before = answers(c)
        assert server.stop() in (0, -15)
    rgb = data_dir / "rgb.faiss"
    rgb.write_bytes(rgb.read_bytes()[: rgb.stat().st_size // 2])  # truncated, tag untouched
    (data_dir / "depth.faiss.json").write_text('{"generation": ')  # a truncated tag
    rgbd = bytearray((data_dir / "rgbd.faiss").read_bytes())
    rgbd[-20] ^= 0xFF  # one descriptor's bytes changed: only the checksum can tell
    (data_dir / "rgbd.faiss").write_bytes(bytes(rgbd))
    with Server(data_dir, posedesc_models, ENV) as server:
        server.wait_ready()
        assert set(check_consistent(server, data_dir).values()) == {"L", "T"}
        with httpx.Client(base_url=server.url, timeout=60) as c:
            after = answers(c)
        assert server.stop() in (0, -15)
    for model in MODELS:  # the same answers as before the damage, to the last digit of the distances
        assert after[model] == before[model], model
    log = server.log.read_text()
    assert log.count("building it from SQLite") == 3 and "Traceback" not in log


@pytest.fixture(scope="module")
def stored(tmp_path_factory, posedesc_models, l_shape) -> Path:
    """A data dir with one object, the server stopped (store.sqlite checkpointed, no WAL)."""
    data_dir = tmp_path_factory.mktemp("stored") / "data"
    with Server(data_dir, posedesc_models, ENV) as server:
        server.wait_ready()
        with httpx.Client(base_url=server.url, timeout=60) as c:
            wait_job(c, post_mesh(c, l_shape, "L"))
        assert server.stop() in (0, -15)
    assert not (data_dir / "store.sqlite-wal").exists()
    return data_dir


def _damage(path: Path, how: str) -> None:
    data = bytearray(path.read_bytes())
    if how == "header":
        data[:100] = bytes(100)
    elif how == "truncated":
        del data[len(data) // 2 :]
    else:  # garbage over the first b-tree page of a table
        db = sqlite3.connect(path)
        (page,) = db.execute("SELECT rootpage FROM sqlite_master WHERE name = ?", (how,)).fetchone()
        (size,) = db.execute("PRAGMA page_size").fetchone()
        db.close()
        data[(page - 1) * size : page * size] = (
            np.random.default_rng(0).integers(0, 256, size, np.uint8).tobytes()
        )
    path.write_bytes(bytes(data))


@pytest.mark.slow  # a store registered, then `posedesc serve` started four times: `make test`, not `make check`
@pytest.mark.parametrize("how", ["header", "truncated", "templates", "objects"])
def test_a_damaged_store_stops_serve_with_one_line(tmp_path, posedesc_models, stored, how):
    data_dir = tmp_path / "data"
    shutil.copytree(stored, data_dir)
    db = data_dir / "store.sqlite"
    _damage(db, how)
    damaged = hashlib.sha256(db.read_bytes()).hexdigest()
    cmd = serve_command(free_port(), data_dir, posedesc_models)
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    assert f"error: {db}" in done.stderr and ("damaged" in done.stderr or "not a usable store" in done.stderr)
    assert hashlib.sha256(db.read_bytes()).hexdigest() == damaged  # left as it was, for a human to look at
