"""A misnamed form field (`image` for `rgb`) is named in a 422 with the fields the endpoint takes, rather
than ignored and answered as if nothing was sent; a field sent twice is refused rather than one of its
values taken."""

from __future__ import annotations

import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_helpers import ply_bytes, png, service_settings, wait_ready

from service.main import create_app

RECOGNIZE = "rgb, depth, depth_scale, fx, fy, cx, cy, u, v, distance_mm, k, max_detections, min_confidence, cam_K, window_mm, dist_coeffs"


@pytest.fixture(scope="module")
def client(tmp_path_factory, posedesc_models):
    settings = service_settings(tmp_path_factory.mktemp("data"), posedesc_models, level=1)
    with TestClient(create_app(settings)) as c:
        wait_ready(c)
        yield c


def test_a_misnamed_image_field_is_named(client):
    patch = png(np.full((64, 64, 3), 120, np.uint8))
    r = client.post("/recognize", files={"image": ("p.png", patch)})
    assert r.status_code == 422
    assert r.json()["detail"] == f"unexpected form field `image`; this endpoint takes {RECOGNIZE}"
    r = client.post("/recognize", files={"rgb": ("p.png", patch)}, data={"focal": "500", "K": "3"})
    assert r.status_code == 422 and r.json()["detail"].startswith("unexpected form fields `K`, `focal`;")
    assert client.post("/recognize", files={"rgb": ("p.png", patch)}, data={"k": "3"}).status_code == 200


def test_a_misnamed_mesh_field_is_named(client, l_shape):
    r = client.post("/objects", files={"file": ("l.ply", ply_bytes(l_shape))}, data={"name": "L"})
    assert r.status_code == 422
    assert (
        r.json()["detail"]
        == "unexpected form field `file`; this endpoint takes mesh, name, units, symmetry, viewpoints"
    )
    assert client.get("/objects").json() == []  # nothing registered


def test_a_field_sent_twice_is_refused_rather_than_one_of_its_values_taken(client):
    patch = png(np.full((64, 64, 3), 120, np.uint8))
    r = client.post("/recognize", files={"rgb": ("p.png", patch)}, data={"k": ["3", "5"]})
    assert r.status_code == 422 and r.json()["detail"] == "form field k sent more than once: send each once"
    two = [("rgb", ("p.png", patch)), ("rgb", ("q.png", patch))]
    r = client.post("/recognize", files=two)
    assert r.status_code == 422 and "rgb sent more than once" in r.json()["detail"]
