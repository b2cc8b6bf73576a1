"""At most MAX_QUEUED registrations wait at once, even when the uploads arrive together: the place in the
queue is taken in the same step as the check (`Jobs.new(limit=...)`), not after the upload was parsed."""

from __future__ import annotations

import threading
import time

import httpx
import pytest
import uvicorn
from service_helpers import created, free_port, ply_bytes, service_settings, wait_ready

from service.jobs import Busy, Jobs
from service.main import create_app
from service.routes.objects import MAX_QUEUED

HANG = 300.0  # seconds: only against a hang, never a measure of speed


def test_jobs_count_and_add_in_one_step():
    jobs, start = Jobs(), threading.Barrier(40)
    made: list[str] = []
    refused: list[str] = []

    def new(i: int) -> None:
        start.wait()
        try:
            made.append(jobs.new(f"o{i}", limit=5).job_id)
        except Busy as e:
            refused.append(str(e))

    threads = [threading.Thread(target=new, args=(i,)) for i in range(40)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(made) == 5 and len(refused) == 35 and jobs.running() == 5
    jobs.discard(jobs.get(made[0]))  # an upload refused later gives its place back
    assert jobs.running() == 4 and jobs.new("again", limit=5).status == "running"


@pytest.mark.slow  # a real server and 20 uploads: about 11 s
def test_concurrent_uploads_beyond_the_queue_get_503(tmp_path, posedesc_models, t_shape):
    """The real app under uvicorn on a loopback port, in this process so the test can hold the registration
    thread: a task of its own waits on a gate there, so no registration finishes while the uploads arrive,
    on any machine, however fast. Exactly MAX_QUEUED uploads get a place; once the gate opens, all of them
    register."""
    n = MAX_QUEUED + 4
    ply, start = ply_bytes(t_shape), threading.Barrier(n)
    answers: list[httpx.Response] = []
    settings = service_settings(tmp_path / "data", posedesc_models, level=1, sync_seconds=0.0)
    app = create_app(settings)
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=free_port(), log_level="warning"))
    url = f"http://127.0.0.1:{server.config.port}"
    serving = threading.Thread(target=server.run, daemon=True)
    serving.start()
    gate = threading.Event()

    def upload(i: int) -> None:
        with httpx.Client(base_url=url, timeout=HANG) as c:
            start.wait()
            answers.append(c.post("/objects", files={"mesh": ("t.ply", ply)}, data={"name": f"t{i}"}))

    try:
        with httpx.Client(base_url=url, timeout=HANG) as c:
            until(lambda: server.started, "uvicorn did not start")
            wait_ready(c, timeout=HANG)
            held = app.state.posedesc.registrar.submit(gate.wait)  # the one registration thread, held
            threads = [threading.Thread(target=upload, args=(i,)) for i in range(n)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            codes = sorted(r.status_code for r in answers)
            assert codes == [202] * MAX_QUEUED + [503] * (n - MAX_QUEUED), [r.text for r in answers]
            busy = next(r for r in answers if r.status_code == 503)
            assert busy.json() == {"detail": "too many registrations queued; try again in a minute"}
            gate.set()
            held.result(timeout=HANG)
            for r in answers:
                if r.status_code == 202:
                    created(c, r, timeout=HANG)
            assert len(c.get("/objects").json()) == MAX_QUEUED
    finally:
        gate.set()
        server.should_exit = True
        serving.join(timeout=HANG)


def until(check, what: str) -> None:
    """Polls `check()`; HANG only stops a test that would never end."""
    end = time.monotonic() + HANG
    while not check():
        assert time.monotonic() < end, what
        time.sleep(0.05)
