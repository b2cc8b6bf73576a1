"""`posedesc.client`, the standard-library client, against `posedesc serve` on a loopback port: every
method, a registration followed through its job, errors as ApiError with the service's message; and it
imports nothing outside the standard library (a Python without site-packages imports it)."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest
from service_helpers import ROOT, Server, frame, free_port, ply_bytes, png

from index.geometry.pose import View
from posedesc.client import ApiError, Client

KEY = "s3cret"
VIEW, UV = View(azimuth=250.0, elevation=55.0, inplane=0.0, distance=700.0), (260.0, 300.0)
CAMERA = {"fx": 572.4, "fy": 573.6, "cx": 325.3, "cy": 242.0}


def test_the_client_needs_only_the_standard_library():
    # -I: no user site, no PYTHON* variables, not the current directory; -S: no site-packages at all
    code = (
        f"import sys; sys.path.insert(0, {str(ROOT)!r}); import posedesc.client; "
        "print(' '.join(sorted({m.split('.')[0] for m in sys.modules} - set(sys.stdlib_module_names) - {'__main__'})))"
    )
    r = subprocess.run([sys.executable, "-I", "-S", "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["posedesc"]  # itself, and the standard library only


@pytest.fixture(scope="module")
def server(tmp_path_factory, posedesc_models):
    # SYNC_SECONDS=0: every registration answers 202 with a job, which the client follows
    env = {"POSEDESC_API_KEY": KEY, "POSEDESC_SYNC_SECONDS": "0", "POSEDESC_LEVEL": "1"}
    with Server(tmp_path_factory.mktemp("client") / "data", posedesc_models, env=env) as s:
        s.wait_ready()
        yield s


def test_every_method_against_a_real_server(server, tmp_path, renderer, l_shape, t_shape):
    api = Client(server.url, api_key=KEY, timeout=60)
    ready = api.health()
    assert ready["status"] == "ready" and ready["objects"] == 0

    mesh = tmp_path / "ell.ply"
    mesh.write_bytes(ply_bytes(l_shape))
    ell = api.register(mesh)  # a path; its name from the file; the 202's job followed to the end
    assert ell["name"] == "ell" and ell["templates"] > 0
    # (the tests' models are untrained: recognised while it is the only object, the answer is its own)
    rgb, depth = frame(renderer, l_shape, VIEW, UV)
    colour = api.recognize(png(rgb), **CAMERA, u=UV[0], v=UV[1], distance_mm=700, k=3)  # bytes
    assert colour["best"]["object_id"] == ell["object_id"] and 1 <= len(colour["matches"]) <= 3
    job = api.register(ply_bytes(t_shape), "T", filename="t.ply", symmetry="none", wait=False)
    assert set(job) >= {"job_id", "status"} and job["status"] == "running"
    while (done := api.job(job["job_id"]))["status"] == "running":
        time.sleep(0.1)
    assert done["status"] == "done" and done["progress"]["done"] == done["progress"]["total"]
    assert [(o["name"], o["demo"]) for o in api.objects()] == [("ell", False), ("T", False)]

    files = tmp_path / "rgb.png", tmp_path / "depth.png"
    files[0].write_bytes(png(rgb))
    files[1].write_bytes(png((depth * 10).round().astype("uint16")))  # in 0.1 mm: said with depth_scale
    both = api.recognize(*files, **CAMERA, u=UV[0], v=UV[1], distance_mm=700, depth_scale=0.1)
    assert both["model"] == "posedesc-rgbd" and both["matches"][0]["name"] in {"ell", "T"}

    with pytest.raises(ApiError) as e:
        api.recognize()
    assert e.value.status == 422 and e.value.message == "send an `rgb` image, a `depth` image, or both"
    with pytest.raises(ApiError) as e:
        api.recognize(png(rgb), image=1)  # a misnamed field, passed through as the form has it
    assert e.value.status == 422 and "unexpected form field `image`" in e.value.message
    with pytest.raises(ApiError) as e:
        api.register(mesh, "ell")
    assert e.value.status == 409 and f"id {ell['object_id']}" in e.value.message
    with pytest.raises(ApiError) as e:
        Client(server.url).register(mesh, "other")  # without the key
    assert e.value.status == 401 and "X-API-Key" in e.value.message

    removed = api.delete(ell["object_id"])
    assert removed["name"] == "ell" and removed["object_id"] == ell["object_id"]
    with pytest.raises(ApiError) as e:
        api.delete(ell["object_id"])
    assert e.value.status == 404 and e.value.message == f"no object {ell['object_id']}"
    assert "ell" not in {o["name"] for o in api.objects()}


def test_an_unreachable_service_is_an_api_error():
    with pytest.raises(ApiError) as e:
        Client(f"http://127.0.0.1:{free_port()}", timeout=5).health()
    assert e.value.status == 0 and "cannot reach" in str(e.value)
