"""Two real `posedesc serve` replicas (uvicorn on loopback, subprocesses) sharing one real Milvus (the
session's server) and one data directory: what one does, the other sees (how soon: `posedesc bench --only
milvus`, its propagation figures); both give the same answers, compared answer by answer (object,
template, pose, confidence) for patches and frames, colour, depth and RGB-D, after registrations racing on
both, a deletion, a restart; a replica started on a directory of its own is never ready and never answers;
an object whose files go missing is answered by no replica until they are back; concurrent recognitions
while objects come and go; a replica SIGKILLed mid-registration; Milvus restarted under them.
Answers are k = 100 on plain patches: more than all the templates of these small stores, so each answer
shows exactly which objects the replica searched."""

from __future__ import annotations

import threading
import time
import uuid

import httpx
import numpy as np
import pytest
from service_helpers import Server, depth_png, frame, frame_fields, patch_files, ply_bytes, png

from index.geometry.pose import View

# the session's Milvus: one worker under pytest-xdist (`make test`) has it
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("services")]

PATCHES = patch_files()
HANG = 300.0  # seconds: only stops a wait that would never end, not a measure of speed


def env(milvus, prefix: str) -> dict[str, str]:
    return {
        "POSEDESC_STORE": milvus.uri,
        "POSEDESC_STORE_PREFIX": prefix,
        "POSEDESC_LEVEL": "1",  # 16 views: short registrations
        "POSEDESC_SYNC_SECONDS": "0",  # every registration answers 202: its job is polled on the other replica
        "POSEDESC_STORE_SWEEP_SECONDS": "6",
    }


@pytest.fixture(scope="module")
def replicas(milvus, posedesc_models, tmp_path_factory):
    shared = tmp_path_factory.mktemp("replicas") / "data"
    settings = env(milvus, f"r{uuid.uuid4().hex[:8]}")
    servers = [Server(shared, posedesc_models, settings), Server(shared, posedesc_models, settings)]
    for s in servers:
        s.wait_ready()
    yield servers, shared, settings
    for s in servers:
        s.stop()
    for s in servers:
        assert "Traceback" not in s.log.read_text(), s.log.read_text()[-3000:]


def post(url: str, mesh, name: str) -> httpx.Response:
    files = {"mesh": (f"{name}.ply", ply_bytes(mesh))}
    return httpx.post(f"{url}/objects", files=files, data={"name": name}, timeout=60)


def finish(url: str, job_id: str) -> dict:
    end = time.monotonic() + HANG
    while (job := httpx.get(f"{url}/jobs/{job_id}", timeout=30).json())["status"] == "running":
        assert time.monotonic() < end, "registration did not finish"
        time.sleep(0.05)
    return job


def seen(url: str) -> dict[str, set[int]]:
    """Per model, the objects of every answer to a plain patch (k = 100)."""
    out = {}
    for model, files in PATCHES.items():
        r = httpx.post(f"{url}/recognize", files=files, data={"k": "100"}, timeout=30)
        assert r.status_code == 200, r.text
        out[model] = {m["object_id"] for m in r.json()["matches"]}
    return out


def until(check, what: str = "never seen") -> None:
    """Polls `check()` until it is true (HANG only stops a wait that would never end)."""
    end = time.monotonic() + HANG
    while not check():
        assert time.monotonic() < end, what
        time.sleep(0.02)


def listed(url: str) -> dict[int, str]:
    return {o["object_id"]: o["name"] for o in httpx.get(f"{url}/objects", timeout=30).json()}


def test_register_on_one_recognise_and_delete_on_the_other(replicas, l_shape, t_shape):
    (a, b), _, _ = replicas
    r = post(a.url, l_shape, "L")
    assert r.status_code == 202, r.text
    job = finish(b.url, r.json()["job_id"])  # polled on the replica that does not run it
    assert job["status"] == "done", job
    oid = job["object_id"]
    until(lambda: oid in listed(b.url))
    assert all(oid in s for s in seen(b.url).values())
    # one name, across replicas: 409 at once, naming the object
    r = post(b.url, t_shape, "L")
    assert r.status_code == 409 and f"object_id {oid}" in r.json()["detail"]
    assert httpx.delete(f"{b.url}/objects/{oid}", timeout=30).status_code == 204
    until(lambda: httpx.get(f"{a.url}/objects/{oid}", timeout=30).status_code == 404)
    assert all(oid not in s for s in seen(a.url).values())
    assert httpx.delete(f"{a.url}/objects/{oid}", timeout=30).status_code == 404


def test_recognitions_while_objects_come_and_go(replicas, l_shape, t_shape):
    """Each replica, once it answers 404 for a deleted object, never answers a recognition with it again;
    every recognition succeeds meanwhile."""
    (a, b), _, _ = replicas
    stop = threading.Event()
    gone: dict[tuple[str, int], float] = {}  # (replica, object) -> when that replica first said 404
    started: dict[str, list[float]] = {a.url: [], b.url: []}  # when each recognition started, per replica
    problems: list[str] = []

    def recognise(url: str) -> None:
        with httpx.Client(base_url=url, timeout=HANG) as c:
            while not stop.is_set():
                for files in PATCHES.values():
                    t0 = time.monotonic()
                    r = c.post("/recognize", files=files, data={"k": "100"})
                    started[url].append(t0)
                    if r.status_code != 200:
                        problems.append(f"{url}: {r.status_code} {r.text[:200]}")
                        continue
                    for m in r.json()["matches"]:
                        said = gone.get((url, m["object_id"]))
                        if said is not None and t0 > said:
                            problems.append(f"{url}: object {m['object_id']} answered after its 404")

    def said_gone(url: str, oid: int) -> bool:
        if httpx.get(f"{url}/objects/{oid}", timeout=HANG).status_code != 404:
            return False
        gone[(url, oid)] = time.monotonic()  # once the 404 came: a recognition started later follows it
        return True

    threads = [threading.Thread(target=recognise, args=(s.url,)) for s in (a, b)]
    for t in threads:
        t.start()
    try:
        for i, mesh in enumerate([l_shape, t_shape, l_shape]):
            here, there = (a, b) if i % 2 == 0 else (b, a)
            job = finish(there.url, post(here.url, mesh, f"churn-{i}").json()["job_id"])
            assert job["status"] == "done", job
            oid = job["object_id"]
            assert httpx.delete(f"{there.url}/objects/{oid}", timeout=30).status_code == 204
            for url in (a.url, b.url):
                until(lambda url=url, oid=oid: said_gone(url, oid), f"{url} still lists object {oid}")
        # recognitions go on after the last 404: each replica answers a few more that must not show it
        last = max(gone.values())
        until(lambda: all(sum(t > last for t in list(ts)) >= 2 * len(PATCHES) for ts in started.values()))
    finally:
        stop.set()
        for t in threads:
            t.join()
    assert problems == []


def test_a_replica_killed_mid_registration_leaves_no_half_object(replicas, posedesc_models, t_shape, milvus):
    (a, b), shared, settings = replicas
    from pymilvus import MilvusClient

    client = MilvusClient(milvus.uri)
    before = set(listed(b.url))
    r = post(a.url, t_shape, "half")
    assert r.status_code == 202
    # the templates go in just before the record turns live: kill while they are being written
    prefix = settings["POSEDESC_STORE_PREFIX"]
    pending = []
    end = time.monotonic() + HANG
    while not pending and time.monotonic() < end:
        pending = client.query(f"{prefix}_objects", filter="state == 0", output_fields=["object_id"])
    a.kill()
    assert pending, "the registration never wrote its pending record"
    oid = pending[0]["object_id"]
    # the other replica never shows it, nor answers with it, and says the job failed once `a` is stale
    for _ in range(10):
        assert oid not in listed(b.url) and all(oid not in s for s in seen(b.url).values())
    job = finish(b.url, r.json()["job_id"])
    assert job["status"] in ("failed", "done"), job
    if job["status"] == "failed":
        assert "stopped" in job["error"]
    # its remains are swept (pending for longer than POSEDESC_STORE_SWEEP_SECONDS): no orphan templates
    collections = [c for c in client.list_collections() if c.startswith(f"{prefix}_t_")]

    def orphans() -> int:
        return sum(
            client.query(
                c, filter=f"object_id == {oid}", output_fields=["count(*)"], consistency_level="Strong"
            )[0]["count(*)"]
            for c in collections
        )

    if oid not in listed(b.url):
        until(lambda: orphans() == 0, "orphan templates never swept")
    client.close()
    # a new replica in place of the killed one serves the same store
    again = Server(shared, posedesc_models, settings)
    again.wait_ready()
    replicas[0][0] = again
    assert set(listed(again.url)) == set(listed(b.url)) >= before


def queries(renderer, l_shape) -> list[tuple[dict, dict]]:
    """(files, form) of what the replicas are asked: the plain patches of each model, and a frame of the L
    shape in colour, depth and RGB-D with its centre, and whole (depth: its segments; no objectness model)."""
    uv = (330.0, 250.0)
    rgb, depth = frame(renderer, l_shape, View(40.0, 35.0, 15.0, 600.0), uv)
    c, d = ("f.png", png(rgb)), ("d.png", depth_png(depth))
    centred, whole = (
        frame_fields(uv, k="5"),
        {k: v for k, v in frame_fields(uv).items() if k not in ("u", "v")},
    )
    out: list[tuple[dict, dict]] = [(files, {"k": "5"}) for files in PATCHES.values()]
    out += [
        ({"rgb": c}, {**centred, "distance_mm": "600"}),
        ({"depth": d}, centred),
        ({"rgb": c, "depth": d}, centred),
    ]
    out += [({"depth": d}, whole), ({"rgb": c, "depth": d}, {**whole, "min_confidence": "0"})]
    return out


def answer_of(url: str, files: dict, form: dict) -> list[dict]:
    """A recognition's answers, each reduced to what must agree between replicas; a whole frame's per
    detection."""
    r = httpx.post(f"{url}/recognize", files=files, data=form, timeout=HANG)
    assert r.status_code == 200, r.text
    body = r.json()
    runs = (
        [d["matches"] for d in body["detections"]]
        if body.get("detections") is not None
        else [body["matches"]]
    )
    return [
        [
            {k: m[k] for k in ("object_id", "azimuth", "elevation", "inplane", "R", "t", "confidence")}
            for m in ms
        ]
        for ms in runs
    ]


def assert_same_answers(a: str, b: str, asked: list[tuple[dict, dict]]) -> None:
    for files, form in asked:
        x, y = answer_of(a, files, form), answer_of(b, files, form)
        assert len(x) == len(y), (form, x, y)
        for mx, my in zip(x, y, strict=True):
            assert [m["object_id"] for m in mx] == [m["object_id"] for m in my], (form, mx, my)
            for p, q in zip(mx, my, strict=True):
                for key in ("azimuth", "elevation", "inplane", "confidence"):
                    assert p[key] == pytest.approx(q[key], abs=1e-4), (form, key, p, q)
                assert np.allclose(p["R"], q["R"], atol=1e-5) and np.allclose(p["t"], q["t"], atol=1e-3), (
                    p,
                    q,
                )


def test_both_replicas_answer_alike_through_races_a_deletion_and_a_restart(
    replicas, renderer, l_shape, t_shape
):
    (a, b), shared, settings = replicas
    asked = queries(renderer, l_shape)
    # registrations racing on both replicas at once
    jobs = {}
    threads = [
        threading.Thread(target=lambda u=u, m=m, n=n: jobs.update({n: post(u, m, n).json()["job_id"]}))
        for u, m, n in ((a.url, l_shape, "same-L"), (b.url, t_shape, "same-T"))
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    done = {n: finish(a.url, j) for n, j in jobs.items()}
    assert all(j["status"] == "done" for j in done.values()), done
    for url in (a.url, b.url):
        until(lambda url=url: {j["object_id"] for j in done.values()} <= set(listed(url)))
    assert_same_answers(a.url, b.url, asked)
    # one deleted on A, another registered in its place on B: both again alike
    assert httpx.delete(f"{a.url}/objects/{done['same-T']['object_id']}", timeout=30).status_code == 204
    job = finish(b.url, post(b.url, t_shape, "same-T2").json()["job_id"])
    assert job["status"] == "done", job
    for url in (a.url, b.url):
        until(
            lambda url=url: done["same-T"]["object_id"] not in listed(url) and job["object_id"] in listed(url)
        )
    assert_same_answers(a.url, b.url, asked)
    # B restarted: ready, and alike at once
    b.stop()
    again = Server(shared, b.models, settings)
    again.wait_ready()
    replicas[0][1] = again
    assert_same_answers(a.url, again.url, asked)


def test_a_replica_on_a_directory_of_its_own_is_never_ready_and_never_answers(
    replicas, posedesc_models, tmp_path, l_shape
):
    (a, _), _, settings = replicas
    job = finish(a.url, post(a.url, l_shape, "seen-by-a").json()["job_id"])
    assert job["status"] == "done", job
    wrong = Server(tmp_path / "data", posedesc_models, settings)
    try:
        until(lambda: _up(wrong.url), "the replica never started")
        for _ in range(20):  # a few seconds of polls: never ready, never an answer
            r = httpx.get(f"{wrong.url}/readyz", timeout=30)
            assert r.status_code == 503 and "mount the directory" in r.json()["detail"], r.text
            for files in PATCHES.values():
                r = httpx.post(f"{wrong.url}/recognize", files=files, data={"k": "5"}, timeout=30)
                assert (
                    r.status_code == 503 and "is not the one the store's replicas share" in r.json()["detail"]
                )
            time.sleep(0.1)
        assert httpx.get(f"{a.url}/readyz", timeout=30).status_code == 200  # the others serve on
    finally:
        wrong.stop()


def test_an_object_whose_files_are_missing_is_answered_by_no_replica_until_they_are_back(replicas, l_shape):
    (a, b), shared, _ = replicas
    job = finish(b.url, post(b.url, l_shape, "files").json()["job_id"])
    assert job["status"] == "done", job
    oid = job["object_id"]
    mesh = shared / "meshes" / f"{oid}.glb"
    aside = shared.parent / f"{oid}.glb.aside"
    mesh.rename(aside)
    try:
        for url in (a.url, b.url):
            until(lambda url=url: httpx.get(f"{url}/readyz", timeout=30).status_code == 503, "still ready")
            r = httpx.get(f"{url}/readyz", timeout=30)
            assert f"object {oid}: meshes/{oid}.glb" in r.json()["detail"], r.text
            r = httpx.post(f"{url}/recognize", files=PATCHES["rgb"], data={"k": "5"}, timeout=30)
            assert r.status_code == 503 and f"object {oid}" in r.json()["detail"], r.text
    finally:
        aside.rename(mesh)
    for url in (a.url, b.url):
        until(lambda url=url: httpx.get(f"{url}/readyz", timeout=30).status_code == 200, "never ready again")
        assert oid in seen(url)["rgb"]


def _up(url: str) -> bool:
    try:
        return httpx.get(f"{url}/healthz", timeout=2).status_code == 200
    except httpx.HTTPError:
        return False


def test_milvus_restarted_under_the_replicas(replicas, milvus, l_shape):
    (a, b), _, _ = replicas
    job = finish(a.url, post(b.url, l_shape, "survivor").json()["job_id"])
    assert job["status"] == "done", job
    oid = job["object_id"]
    until(lambda: oid in listed(a.url))
    milvus.stop()
    try:
        for url in (a.url, b.url):
            r = httpx.post(f"{url}/recognize", files=PATCHES["rgb"], data={"k": "5"}, timeout=30)
            assert r.status_code == 503 and "Milvus" in r.json()["detail"], r.text
            r = httpx.delete(f"{url}/objects/{oid}", timeout=30)
            assert r.status_code == 503 and "Milvus" in r.json()["detail"], r.text
            until(lambda url=url: httpx.get(f"{url}/readyz", timeout=30).status_code == 503)
        r = post(a.url, l_shape, "while-down")
        if r.status_code == 202:  # accepted, then failed in the job: polled on the other replica
            job = finish(b.url, r.json()["job_id"])
            assert job["status"] == "failed" and "Milvus" in job["error"], job
        else:
            assert r.status_code == 503, r.text
    finally:
        milvus.start()
    # the replicas recover without a restart: ready again, the object found on both
    for url in (a.url, b.url):
        until(lambda url=url: httpx.get(f"{url}/readyz", timeout=30).status_code == 200)
        # ready means its collections are loaded again: searches work at once
        assert oid in seen(url)["rgb"]


def _answers(url: str) -> bool:
    r = httpx.post(f"{url}/recognize", files=PATCHES["rgb"], data={"k": "5"}, timeout=30)
    return r.status_code == 200
