"""A registration job tells how far it is (`GET /jobs/{id}`'s `progress`): seen from inside the running
registration (a hook on its progress callback asks the API at each step, so no race decides what is seen),
and at the end, where every template is stored."""

from __future__ import annotations

import threading
import time

from fastapi.testclient import TestClient
from service_helpers import ply_bytes, service_settings, wait_ready

from service import state
from service.main import create_app


def test_a_registration_job_reports_its_progress(tmp_path, posedesc_models, l_shape, monkeypatch):
    real = state.register  # what `AppState.register_mesh` calls for `POST /objects`
    job_id: list[str] = []
    answered = threading.Event()  # the 202 is in: the hook knows which job to ask about
    seen: list[dict] = []

    def hooked(*args, progress, **kw):
        def told(stage: str, done: int, total: int) -> None:
            progress(stage, done, total)  # the service's own callback: the job is updated first
            assert answered.wait(60)
            seen.append(c.get(f"/jobs/{job_id[0]}").json())

        return real(*args, progress=told, **kw)

    monkeypatch.setattr(state, "register", hooked)
    settings = service_settings(tmp_path, posedesc_models, sync_seconds=0.0, level=1)
    with TestClient(create_app(settings)) as c:
        wait_ready(c)
        r = c.post("/objects", files={"mesh": ("l.ply", ply_bytes(l_shape))}, data={"name": "L"})
        assert r.status_code == 202, r.text
        job_id.append(r.json()["job_id"])
        answered.set()
        end = time.monotonic() + 120
        while (job := c.get(f"/jobs/{job_id[0]}").json())["status"] == "running":
            assert time.monotonic() < end
            time.sleep(0.05)
        stored = sum(c.get(f"/objects/{job['object_id']}").json()["templates"].values())

    assert job["status"] == "done"
    assert job["progress"] == {"stage": "store", "done": stored, "total": stored}
    assert all(s["status"] == "running" for s in seen)  # each seen while the registration ran
    steps = [s["progress"] for s in seen]
    assert all(set(p) == {"stage", "done", "total"} and 0 <= p["done"] <= p["total"] for p in steps)
    assert steps[0] == {"stage": "render", "done": 0, "total": steps[0]["total"]}
    assert steps[-1] == {"stage": "store", "done": stored, "total": stored}
    views = [p for p in steps if p["stage"] != "store"]
    assert [p["stage"] for p in views] == ["render", "embed"] * (len(views) // 2)
    done = [p["done"] for p in views if p["stage"] == "embed"]
    assert len(done) > 1 and done == sorted(set(done)) and done[-1] < steps[0]["total"]  # moving
