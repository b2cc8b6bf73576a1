"""Demo objects go only into a data dir that has never held an object: never beside a user's objects, and
not back after the user removed every object. (A fresh dir gets them once: test_api.py.)"""

from __future__ import annotations

import httpx
from fastapi.testclient import TestClient
from service_helpers import Server, register, service_settings, wait_ready

from service.main import create_app, ready_line


def names(c: TestClient) -> list[str]:
    return sorted(o["name"] for o in c.get("/objects").json())


def test_no_demo_objects_beside_a_users_objects(tmp_path, posedesc_models, t_shape):
    with TestClient(create_app(service_settings(tmp_path, posedesc_models, level=1))) as c:
        wait_ready(c)
        register(c, t_shape, "duck")  # the user's own object, by chance under a demo object's name
    demo = service_settings(tmp_path, posedesc_models, level=1, demo_objects=True)
    with TestClient(create_app(demo)) as c:
        assert wait_ready(c)["objects"] == 1
        assert names(c) == ["duck"]


def test_no_demo_objects_into_a_dir_its_user_emptied(tmp_path, posedesc_models, l_shape):
    with TestClient(create_app(service_settings(tmp_path, posedesc_models, level=1))) as c:
        wait_ready(c)
        oid = register(c, l_shape, "L")["object_id"]
        assert c.delete(f"/objects/{oid}").status_code == 204
    demo = service_settings(tmp_path, posedesc_models, level=1, demo_objects=True)
    with TestClient(create_app(demo)) as c:
        assert wait_ready(c)["objects"] == 0
        assert names(c) == []


def test_demo_objects_are_marked_and_the_ready_line_says_how_to_be_rid_of_them(
    tmp_path, posedesc_models, t_shape
):
    demo = service_settings(tmp_path, posedesc_models, level=1, demo_objects=True)
    with TestClient(create_app(demo)) as c:
        ready = wait_ready(c)
        register(c, t_shape, "T")
        listed = c.get("/objects").json()
        snap = c.app.state.posedesc.store.snapshot
        line = ready_line(snap, "http://127.0.0.1:8000")
    assert {o["name"]: o["demo"] for o in listed} == {
        "demo-mug": True,
        "demo-lamp": True,
        "demo-robot": True,
        "demo-duck": True,
        "T": False,
    }
    ids = {o["name"]: o["object_id"] for o in listed}
    assert line.startswith("ready on http://127.0.0.1:8000: 5 objects (4 of them demo objects, ")
    demo_ids = [ids[f"demo-{n}"] for n in ("duck", "lamp", "mug", "robot")]
    assert "demo-duck ({}), demo-lamp ({}), demo-mug ({}), demo-robot ({})".format(*demo_ids) in line
    assert "curl -X DELETE 'http://127.0.0.1:8000/objects?demo=true'" in line
    assert "curl -X DELETE http://127.0.0.1:8000/objects/ID" in line
    assert "posedesc serve --no-demo" in line and "POSEDESC_DEMO_OBJECTS=false" in line
    # the templates it counts are every template each model searches: in-plane variants included
    per_model = {m: sum(o["templates"][m] for o in listed) for m in ready["templates"]}
    shown = ", ".join(f"{m} {n}" for m, n in sorted(per_model.items()))
    assert line.endswith(f"templates searched (all objects, viewpoints x in-plane angles): {shown}"), line


def test_one_call_removes_the_demo_objects_and_only_them(tmp_path, posedesc_models, t_shape):
    demo = service_settings(tmp_path, posedesc_models, level=1, demo_objects=True)
    with TestClient(create_app(demo)) as c:
        wait_ready(c)
        register(c, t_shape, "duck")  # the user's own duck: no demo object has its name
        refused = c.delete("/objects")
        assert refused.status_code == 422 and "?demo=true" in refused.json()["detail"]
        assert len(names(c)) == 5
        demo_ids = sorted(o["object_id"] for o in c.get("/objects").json() if o["demo"])
        r = c.delete("/objects", params={"demo": "true"})
        assert r.status_code == 200 and r.json() == {"removed": demo_ids}
        assert names(c) == ["duck"]
        assert c.delete("/objects", params={"demo": "true"}).json() == {"removed": []}
    with TestClient(create_app(demo)) as c:  # and they do not come back
        wait_ready(c)
        assert names(c) == ["duck"]


def test_serve_no_demo_registers_none(tmp_path, posedesc_models):
    env = {"POSEDESC_DEMO_OBJECTS": "true", "POSEDESC_LEVEL": "1"}
    with Server(tmp_path / "data", posedesc_models, env=env, args=["--no-demo"]) as server:
        server.wait_ready()
        assert httpx.get(f"{server.url}/objects", timeout=10).json() == []
