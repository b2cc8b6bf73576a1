"""Load: clients recognise while another registers and deletes objects, against `posedesc serve` on a
loopback port, until enough has happened to put every rule to the test (DELETIONS deletions, RECOGNITIONS
recognitions, AFTER_DELETE of them started after a deletion), however long that takes on the machine. No request fails; no recognition that started after a DELETE
returned sees that object; every recognition that ran wholly between an object's registration and its
removal sees it; every object registered and not deleted is listed at the end, and after a restart.

Templates: level 1 (16 per object and model) and at most four objects at a time, so k = 100 returns
every template of the store: each answer shows exactly which objects its snapshot held."""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field

import httpx
import numpy as np
import pytest
from service_helpers import Server, patch_files

from index.templates.shapes import random_shape

pytestmark = pytest.mark.slow  # a long service load test: `make test`, not `make check`

DELETIONS = 3  # the writer's deletions before the clients stop
RECOGNITIONS = 30  # recognitions in all
AFTER_DELETE = 6  # recognitions that started after the first deletion returned
HANG = 600.0  # seconds: only stops a run that would never get there, not a measure of speed
CLIENTS = ("rgb", "depth", "rgbd")  # one recogniser per model
KEEP = 3  # objects the writer keeps registered at a time (beside the first one)
QUERY = patch_files()


@dataclass
class Seen:
    start: float
    end: float
    status: int
    objects: set[tuple[int, str]] = field(default_factory=set)


@dataclass
class Life:
    """An object from the writer's side: when its POST returned, when its DELETE started and returned."""

    name: str
    registered: float
    delete_started: float = float("inf")
    deleted: float = float("inf")


def recognise_until(url: str, model: str, stop: threading.Event, out: list[Seen]) -> None:
    with httpx.Client(base_url=url, timeout=HANG) as c:
        while not stop.is_set():
            t0 = time.monotonic()
            r = c.post("/recognize", files=QUERY[model], data={"k": "100"})
            seen = Seen(t0, time.monotonic(), r.status_code)
            if r.status_code == 200:
                seen.objects = {(m["object_id"], m["name"]) for m in r.json()["matches"]}
            out.append(seen)


def write_until(
    url: str, meshes: list[bytes], stop: threading.Event, lives: dict[int, Life], failures: list[str]
):
    alive: deque[int] = deque()
    with httpx.Client(base_url=url, timeout=HANG) as c:
        for i, mesh in enumerate(meshes):
            if stop.is_set():
                return
            r = c.post("/objects", files={"mesh": (f"s{i}.ply", mesh)}, data={"name": f"shape-{i}"})
            if r.status_code != 201:
                failures.append(f"POST /objects: {r.status_code} {r.text}")
                continue
            oid = r.json()["object_id"]
            lives[oid] = Life(f"shape-{i}", time.monotonic())
            alive.append(oid)
            if len(alive) > KEEP:
                gone = alive.popleft()
                lives[gone].delete_started = time.monotonic()
                r = c.delete(f"/objects/{gone}")
                lives[gone].deleted = time.monotonic()
                if r.status_code != 204:
                    failures.append(f"DELETE /objects/{gone}: {r.status_code} {r.text}")


def test_recognitions_during_registrations_and_deletes(tmp_path, posedesc_models, l_shape):
    # sized in the model's window class (docs/windows.md): the patches, sent without `window_mm`, are
    # compared with the objects of the model's window only, so every object is in every answer
    meshes = [
        random_shape(np.random.default_rng(i), diameter_mm=(120.0, 260.0)).export(file_type="ply")
        for i in range(40)
    ]
    data_dir = tmp_path / "data"
    with Server(data_dir, posedesc_models, env={"POSEDESC_LEVEL": "1"}) as server:
        server.wait_ready()
        with httpx.Client(base_url=server.url, timeout=60) as c:
            r = c.post(
                "/objects", files={"mesh": ("L.ply", l_shape.export(file_type="ply"))}, data={"name": "L"}
            )
            assert r.status_code == 201, r.text
        lives = {r.json()["object_id"]: Life("L", time.monotonic())}
        seen: list[Seen] = []
        failures: list[str] = []
        stop = threading.Event()
        threads = [
            threading.Thread(target=recognise_until, args=(server.url, m, stop, seen)) for m in CLIENTS
        ]
        threads.append(threading.Thread(target=write_until, args=(server.url, meshes, stop, lives, failures)))
        for t in threads:
            t.start()

        def enough() -> bool:
            done = sorted(life.deleted for life in list(lives.values()) if life.deleted < float("inf"))
            after = sum(s.start > done[0] for s in list(seen)) if done else 0
            return len(done) >= DELETIONS and len(seen) >= RECOGNITIONS and after >= AFTER_DELETE

        end = time.monotonic() + HANG
        while not enough() and not failures and all(t.is_alive() for t in threads):
            assert time.monotonic() < end, (len(seen), len(lives))
            time.sleep(0.05)
        stop.set()
        for t in threads:
            t.join()

        assert failures == []
        assert [s.status for s in seen if s.status != 200] == []
        deleted = [oid for oid, life in lives.items() if life.deleted < float("inf")]
        assert len(seen) >= RECOGNITIONS and len(deleted) >= DELETIONS, (
            len(seen),
            len(lives),
            len(deleted),
        )
        names = {oid: life.name for oid, life in lives.items()}
        checked_gone = checked_there = 0
        for s in seen:
            assert {
                (oid, names.get(oid)) for oid, _ in s.objects
            } == s.objects  # only real objects, right names
            ids = {oid for oid, _ in s.objects}
            for oid, life in lives.items():
                if s.start > life.deleted:
                    assert oid not in ids, (
                        f"object {oid} seen {s.start - life.deleted:.3f} s after its delete"
                    )
                    checked_gone += 1
                if life.registered < s.start and s.end < life.delete_started:
                    assert oid in ids, f"object {oid} missing from a recognition while registered"
                    checked_there += 1
        assert checked_gone > 0 and checked_there > len(seen)  # both rules were put to the test

        kept = {oid: life.name for oid, life in lives.items() if life.deleted == float("inf")}
        with httpx.Client(base_url=server.url, timeout=60) as c:
            assert {o["object_id"]: o["name"] for o in c.get("/objects").json()} == kept
        assert server.stop() in (0, -15)
        assert "Traceback" not in server.log.read_text()

    with Server(data_dir, posedesc_models, env={"POSEDESC_LEVEL": "1"}) as again:
        again.wait_ready()
        with httpx.Client(base_url=again.url, timeout=60) as c:
            assert {o["object_id"]: o["name"] for o in c.get("/objects").json()} == kept
            for model in CLIENTS:
                r = c.post("/recognize", files=QUERY[model], data={"k": "100"})
                assert {(m["object_id"], m["name"]) for m in r.json()["matches"]} == set(kept.items()), model
