"""`POST /recognize/draw`: the answer `/recognize` gives, drawn over the image sent, as a PNG; bad input as
`/recognize` refuses it. The shipped models, one object registered at level 1."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_helpers import ROOT, K, frame, frame_fields, png, register, service_settings, wait_ready

from index.draw import PATCH_DRAW_PX, DrawMesh, silhouette
from index.features.patches import PatchSpec, crops
from index.geometry.pose import View, view_to_pose
from service.main import create_app

VIEW, UV = View(40.0, 30.0, 0.0, 600.0), (380.0, 250.0)


@pytest.fixture(scope="module")
def client(tmp_path_factory, l_shape):
    settings = service_settings(tmp_path_factory.mktemp("data"), ROOT / "models", level=1, reject_above="off")
    with TestClient(create_app(settings)) as c:
        wait_ready(c)
        register(c, l_shape, "ell")
        yield c


@pytest.fixture(scope="module")
def shot(renderer, l_shape):
    rgb, _ = frame(renderer, l_shape, VIEW, UV)
    return rgb


def decoded(r) -> np.ndarray:
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/png"
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def test_the_frame_comes_back_with_the_answer_drawn_on_the_object(client, shot, l_shape):
    form = frame_fields(UV, distance_mm=VIEW.distance)
    files = {"rgb": ("f.png", png(shot))}
    drawn = decoded(client.post("/recognize/draw", files=files, data=form))
    assert drawn.shape == shot.shape
    changed = (drawn != shot).any(axis=2)
    on_object = shot.any(axis=2)  # the background is black
    assert changed[on_object].mean() > 0.5
    # exactly the silhouette of the answer /recognize gives, tinted, and nothing far from it
    best = client.post("/recognize", files=files, data=form).json()["best"]
    R, t = np.reshape(best["R"], (3, 3)), np.array(best["t"])
    answer = silhouette(DrawMesh.of(l_shape), R, t, K, shot.shape[:2]) > 0
    assert changed[answer].mean() > 0.95
    ys, xs = np.nonzero(answer | on_object)
    near = np.zeros_like(changed)
    near[max(0, ys.min() - 80) : ys.max() + 80, max(0, xs.min() - 80) : xs.max() + 200] = True
    assert changed.sum() > 1000 and not changed[~near].any()


def test_a_patch_is_drawn_upscaled(client, shot):
    spec = PatchSpec()
    ray = np.linalg.inv(K) @ np.array([UV[0], UV[1], 1.0])
    _, t = view_to_pose(VIEW, ray)
    patch, _ = crops(shot, None, K, UV, float(np.linalg.norm(t)), spec, [0.0])
    files = {"rgb": ("p.png", png(patch[0]))}
    drawn = decoded(client.post("/recognize/draw", files=files, data={"distance_mm": str(VIEW.distance)}))
    assert drawn.shape == (PATCH_DRAW_PX, PATCH_DRAW_PX, 3)
    # the origin of an answer on the patch camera's axis: the axes' white dot at the centre
    c = PATCH_DRAW_PX // 2
    assert (drawn[c - 1 : c + 1, c - 1 : c + 1] > 200).all()


def test_draw_k_draws_more_answers(client, shot):
    form = frame_fields(UV, distance_mm=VIEW.distance)
    files = {"rgb": ("f.png", png(shot))}
    one = decoded(client.post("/recognize/draw", files=files, data=form))
    three = decoded(client.post("/recognize/draw", files=files, data={**form, "k": "3", "draw_k": "3"}))
    assert (three != one).any()


@pytest.mark.parametrize(
    "files,data,message",
    [
        ({}, {}, "send an `rgb` image, a `depth` image, or both"),
        ({"rgb": ("f.png", b"not a png")}, {}, "rgb"),
        ("frame", {"fx": "572.4"}, "missing: fy, cx, cy"),
        ("frame", {"k": "2", "draw_k": "3"}, "draw_k: at most k (2)"),
        ("frame", {"draw_k": "0"}, "draw_k"),
        ("frame", {"image": "x"}, "unexpected form field `image`; this endpoint takes rgb, depth, "),
    ],
)
def test_bad_input_is_a_json_422(client, shot, files, data, message):
    if files == "frame":
        files = {"rgb": ("f.png", png(shot))}
    r = client.post("/recognize/draw", files=files, data=data)
    assert r.status_code == 422 and r.headers["content-type"] == "application/json"
    assert message in r.json()["detail"]


def test_the_misnamed_field_message_lists_draw_k_last(client, shot):
    r = client.post("/recognize/draw", files={"rgb": ("f.png", png(shot))}, data={"image": "x"})
    assert r.json()["detail"].endswith(
        "k, max_detections, min_confidence, cam_K, window_mm, dist_coeffs, draw_k"
    )
