"""Objects from 20 mm to 2 m through the service: each registers with its true units, is seen through the
window its size asks for (kept over a restart), and is recognised in a rendered frame with its centre given,
the query cut once per window class. The shipped rgb model, a real renderer, a real store."""

from __future__ import annotations

import shutil

import pytest
from fastapi.testclient import TestClient
from service_helpers import ROOT, frame, frame_fields, png, register, service_settings, wait_ready

from index.geometry.pose import View
from index.templates.mesh import diameter
from index.templates.windows import window_class
from service.main import create_app

pytestmark = pytest.mark.xdist_group("windows")  # the module's fixtures made once, on one worker

UV = (330.0, 250.0)


@pytest.fixture(scope="module")
def shipped_rgb(tmp_path_factory):
    src = ROOT / "models" / "posedesc-rgb.onnx"
    if not src.is_file():
        pytest.skip("no shipped rgb model")
    folder = tmp_path_factory.mktemp("shipped")
    shutil.copy(src, folder)
    return folder


def scaled(mesh, across_mm: float):
    out = mesh.copy()
    out.apply_scale(across_mm / diameter(mesh))
    return out


@pytest.fixture(scope="module")
def meshes(l_shape, t_shape):
    """The test's objects in mm: an ordinary L, a 1.5 m T, a 25 mm L (the same shape as the ordinary one:
    only its size, seen through its window at the distance sent, tells them apart)."""
    return {"L": l_shape, "big": scaled(t_shape, 1500.0), "small": scaled(l_shape, 25.0)}


# each object seen from a view between template viewpoints, at a distance that suits its size
VIEWS = {
    "L": View(37.0, 28.0, 0.0, 600.0),
    "big": View(37.0, 28.0, 0.0, 4000.0),
    "small": View(37.0, 28.0, 0.0, 120.0),
}


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("data")


@pytest.fixture(scope="module")
def registered(data_dir, shipped_rgb, meshes):
    with TestClient(create_app(service_settings(data_dir, shipped_rgb, level=2))) as c:
        wait_ready(c)
        out = {"L": register(c, meshes["L"], "L")}
        big_in_m = meshes["big"].copy()
        big_in_m.apply_scale(0.001)
        r = c.post(
            "/objects", files={"mesh": ("big.ply", big_in_m.export(file_type="ply"))}, data={"name": "big"}
        )
        assert r.status_code == 422 and "read in m it is 1,500 mm" in r.json()["detail"]  # units not given
        out["big"] = register(c, big_in_m, "big", units="m")
        r = c.post(
            "/objects",
            files={"mesh": ("s.ply", meshes["small"].export(file_type="ply"))},
            data={"name": "small"},
        )
        assert r.status_code == 422 and "units=mm or units=cm" in r.json()["detail"]  # 25 mm, or 250?
        out["small"] = register(c, meshes["small"], "small", units="mm")
    return out


def test_each_registers_with_its_true_size_and_the_window_it_asks_for(registered, meshes):
    for name, obj in registered.items():
        true = diameter(meshes[name])
        assert obj["diameter_mm"] == pytest.approx(true, abs=0.1)
        assert obj["window_mm"] == window_class(true, 200.0)
    assert [registered[n]["window_mm"] for n in ("L", "big", "small")] == [200.0, 1131.37, 50.0]


@pytest.fixture(scope="module")
def frames(renderer, meshes):
    wall = {"L": 1500.0, "big": 9000.0, "small": 400.0}
    return {n: frame(renderer, meshes[n], v, UV, wall_mm=wall[n]) for n, v in VIEWS.items()}


def test_after_a_restart_each_keeps_its_window_and_is_recognised_in_a_frame(
    data_dir, shipped_rgb, registered, frames
):
    with TestClient(create_app(service_settings(data_dir, shipped_rgb, level=2))) as c:
        wait_ready(c)
        listed = {o["name"]: o for o in c.get("/objects").json()}
        assert {n: o["window_mm"] for n, o in listed.items()} == {"L": 200.0, "big": 1131.37, "small": 50.0}
        assert listed["big"]["diameter_mm"] == registered["big"]["diameter_mm"]
        for name, (rgb, _) in frames.items():
            fields = frame_fields(UV, distance_mm=VIEWS[name].distance)
            r = c.post("/recognize", files={"rgb": ("f.png", png(rgb))}, data=fields)
            assert r.status_code == 200, r.text
            assert r.json()["best"]["name"] == name, (name, [m["name"] for m in r.json()["matches"]])


def test_a_patch_is_compared_with_the_objects_of_its_window_only(data_dir, shipped_rgb, registered, frames):
    """A patch spans one window (`window_mm`, the model's by default): it is searched among the objects
    registered through that window, and refused, naming the windows there are, when none has it."""
    import numpy as np
    from service_helpers import K

    from index.features.patches import PatchSpec, crops

    rgb, _ = frames["small"]
    spec = PatchSpec(size=64, window_mm=50.0)
    patch = crops(rgb, None, K, UV, VIEWS["small"].distance, spec, [0.0])[0]
    assert patch is not None
    with TestClient(create_app(service_settings(data_dir, shipped_rgb, level=2))) as c:
        wait_ready(c)
        files = {"rgb": ("p.png", png(np.ascontiguousarray(patch[0])))}
        r = c.post("/recognize", files=files, data={"window_mm": "50", "k": "3"})
        assert r.status_code == 200, r.text
        assert {m["name"] for m in r.json()["matches"]} == {"small"}  # the 50 mm window's objects alone
        r = c.post("/recognize", files=files, data={"k": "3"})  # the model's window: the L's class
        assert r.status_code == 200 and {m["name"] for m in r.json()["matches"]} == {"L"}
        r = c.post("/recognize", files=files, data={"window_mm": "70"})
        assert r.status_code == 422 and "50, 200, 1131.37 mm" in r.json()["detail"], r.text
        r = c.post("/recognize", files={"rgb": ("f.png", png(rgb))}, data=frame_fields(UV, window_mm=50))
        assert r.status_code == 422 and "window_mm is a patch's" in r.json()["detail"], r.text
