"""Demo objects go only into a data dir that has never held an object: never beside a user's objects, and
not back after the user removed every object. (A fresh dir gets them once: test_api.py.)"""

from __future__ import annotations

from fastapi.testclient import TestClient
from service_helpers import register, service_settings, wait_ready

from service.main import create_app


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
