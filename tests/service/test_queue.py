"""At most MAX_QUEUED registrations wait at once, even when the uploads arrive together: the place in the
queue is taken in the same step as the check (`Jobs.new(limit=...)`), not after the upload was parsed."""

from __future__ import annotations

import threading

import httpx
import trimesh
from service_helpers import Server, ply_bytes

from service.jobs import Busy, Jobs
from service.routes.objects import MAX_QUEUED


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


def test_concurrent_uploads_beyond_the_queue_get_503(tmp_path, posedesc_models):
    """Level 3 (301 viewpoints): each registration takes seconds, so none is done while the uploads arrive;
    meshes of 82k triangles take a while to parse (one at a time), so a check made only once the job exists
    would let them all in."""
    n = MAX_QUEUED + 4
    ply, start = ply_bytes(trimesh.creation.icosphere(subdivisions=6, radius=60)), threading.Barrier(n)
    answers: list[httpx.Response] = []

    def upload(url: str, i: int) -> None:
        with httpx.Client(base_url=url, timeout=300) as c:  # parsed one at a time, beside registrations
            start.wait()
            answers.append(c.post("/objects", files={"mesh": ("t.ply", ply)}, data={"name": f"t{i}"}))

    env = {"POSEDESC_LEVEL": "3", "POSEDESC_SYNC_SECONDS": "0"}
    with Server(tmp_path / "data", posedesc_models, env=env) as server:
        server.wait_ready()
        threads = [threading.Thread(target=upload, args=(server.url, i)) for i in range(n)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        codes = sorted(r.status_code for r in answers)
        assert codes == [202] * MAX_QUEUED + [503] * (n - MAX_QUEUED), [r.text for r in answers]
        busy = next(r for r in answers if r.status_code == 503)
        assert busy.json() == {"detail": "too many registrations queued; try again in a minute"}
