"""One object per name: a second registration of a name is refused with 409 and the existing object's id,
whether it is stored already (checked before the upload is parsed) or was queued just before it (checked
again when it is stored). The app runs in-process with its lifespan: real store, renderer, models."""

from __future__ import annotations

import threading

from fastapi.testclient import TestClient
from service_helpers import ply_bytes, register, service_settings, wait_ready

from service.main import create_app


def test_a_second_object_of_one_name_is_refused_with_409(tmp_path, posedesc_models, l_shape, t_shape):
    with TestClient(create_app(service_settings(tmp_path, posedesc_models, level=1))) as c:
        wait_ready(c)
        l_id = register(c, l_shape, "L")["object_id"]
        before = c.get("/objects").json()
        r = c.post("/objects", files={"mesh": ("t.ply", ply_bytes(t_shape))}, data={"name": "L"})
        assert r.status_code == 409, r.text
        assert r.json() == {
            "detail": f"an object named 'L' exists already (object_id {l_id}): delete it first, "
            "or choose another name"
        }
        r = c.post("/objects", files={"mesh": ("x.ply", b"not a mesh")}, data={"name": "L"})
        assert r.status_code == 409  # refused before the upload is even parsed
        assert c.get("/objects").json() == before
        assert c.delete(f"/objects/{l_id}").status_code == 204
        assert register(c, t_shape, "L")["object_id"] != l_id  # a removed object's name is free again


def test_two_queued_registrations_of_one_name(tmp_path, posedesc_models, l_shape, t_shape):
    """Both pass the first check (neither is stored yet); the store refuses the second one, its job says 409."""
    settings = service_settings(tmp_path, posedesc_models, level=1, sync_seconds=0.0)
    with TestClient(create_app(settings)) as c:
        wait_ready(c)
        release = threading.Event()
        c.app.state.posedesc.registrar.submit(release.wait, 60)  # the registration thread is busy meanwhile
        first, second = (
            c.post("/objects", files={"mesh": ("m.ply", ply_bytes(mesh))}, data={"name": "twin"})
            for mesh in (l_shape, t_shape)
        )
        assert first.status_code == second.status_code == 202
        release.set()
        done = register(c, l_shape, "other")  # queued after both: once it is done, so are they
        assert done["name"] == "other"
        one = c.get(f"/jobs/{first.json()['job_id']}").json()
        two = c.get(f"/jobs/{second.json()['job_id']}").json()
        assert one["status"] == "done" and two["status"] == "failed", (one, two)
        assert f"object_id {one['object_id']}" in two["error"] and "exists already" in two["error"]
        assert sorted(o["name"] for o in c.get("/objects").json()) == ["other", "twin"]
