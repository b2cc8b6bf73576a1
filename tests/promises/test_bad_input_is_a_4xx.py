"""Bad input gets a 4xx with a message that says what to do, never a 200 with a silently wrong answer
(README, "Errors"): the cases users met (issue 37) through the real app and its lifespan: depth in the
wrong units for a whole frame, numbers that are no numbers, a principal point off the frame, a distance in
metres, a patch that is not square, a greyscale image sent as colour, more answers drawn than asked for; and
what a fuzzing of the live service answered with a 500 or a 200 of NaN poses (2026-12-08): a `cam_K` whose
focal lengths are zero, negative or absurd, a float depth (`.npy`, TIFF) too small to be a frame."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_helpers import ROOT, service_settings, wait_ready

from service.main import create_app

EXAMPLES = ROOT / "service" / "examples"
CAMERA = {"fx": "572.4", "fy": "573.6", "cx": "325.3", "cy": "242.0"}
CENTRED = {**CAMERA, "u": "380", "v": "250", "distance_mm": "600"}
K_CENTRED = {"u": "380", "v": "250", "distance_mm": "600"}  # with a cam_K instead of fx, fy, cx, cy


def npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def png(a: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", a)
    assert ok
    return data.tobytes()


@pytest.fixture(scope="module")
def client(posedesc_models, tmp_path_factory):
    app = create_app(service_settings(tmp_path_factory.mktemp("bad") / "data", posedesc_models, level=0))
    with TestClient(app) as c:
        wait_ready(c)
        yield c


@pytest.fixture(scope="module")
def images() -> dict[str, bytes]:
    rgb = cv2.imread(str(EXAMPLES / "robot-rgb.png"))
    depth = cv2.imread(str(EXAMPLES / "robot-depth.png"), cv2.IMREAD_UNCHANGED).astype(np.float64)
    return {
        "rgb": (EXAMPLES / "robot-rgb.png").read_bytes(),
        "depth": (EXAMPLES / "robot-depth.png").read_bytes(),
        "depth in 0.1 mm": png(np.clip(depth * 10, 0, 65535).astype(np.uint16)),
        "depth in m": png(np.round(depth / 1000).astype(np.uint16)),
        "grey": png(cv2.cvtColor(rgb, cv2.COLOR_BGR2GRAY)),
        "narrow patch": png(cv2.imread(str(EXAMPLES / "robot-patch.png"))[:, :50]),
        "float depth in m": npy((depth / 1000).astype(np.float32)),
        "float depth in mm": npy(depth.astype(np.float32)),  # sent without saying so: read as metres
        "empty float depth": npy(np.zeros((0, 0), np.float32)),
        "one-row float depth": npy(np.full((1, 640), 0.6, np.float32)),
        "one-column float TIFF": tiff(np.full((640, 1), 0.6, np.float32)),
    }


def tiff(a: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(a).save(buf, format="TIFF")
    return buf.getvalue()


CASES = {
    # name: (files, form, the status, words the message must hold)
    "a whole frame's depth in 0.1 mm": (["depth in 0.1 mm"], CAMERA, 422, ["depth_scale=0.1"]),
    "a whole frame's RGB-D in 0.1 mm": (["rgb", "depth in 0.1 mm"], CAMERA, 422, ["depth_scale=0.1"]),
    "a whole frame's depth in metres": (["depth in m"], CAMERA, 422, ["metres", "16-bit PNG"]),
    "float depth in mm, unsaid": (["float depth in mm"], CAMERA, 422, ["depth_scale=1"]),
    "fx = nan": (["rgb"], {**CENTRED, "fx": "nan"}, 422, ["fx", "finite number"]),
    "cy = inf": (["rgb"], {**CENTRED, "cy": "inf"}, 422, ["cy", "finite number"]),
    "distance_mm = nan": (["rgb"], {**CENTRED, "distance_mm": "nan"}, 422, ["distance_mm", "finite number"]),
    "cx = 99999": (["rgb"], {**CENTRED, "cx": "99999"}, 422, ["cx = 99999", "principal point", "intrinsics"]),
    "cx = 99999, a whole frame": (["rgb"], {**CAMERA, "cx": "99999"}, 422, ["cx = 99999"]),
    "distance_mm = 0.6 (metres)": (["rgb"], {**CENTRED, "distance_mm": "0.6"}, 422, ["distance_mm=600"]),
    "a patch 50 x 64 px": (["narrow patch"], {}, 422, ["square", "fx, fy, cx and cy", "every registered"]),
    "a greyscale image as rgb": (["grey"], CENTRED, 422, ["greyscale", "colour image"]),
    "cam_K of focal length 0": (
        ["rgb"],
        {**K_CENTRED, "cam_K": "0 0 325 0 0 242 0 0 1"},
        422,
        ["cam_K", "fx 0"],
    ),
    "cam_K of a negative fy, a whole depth frame": (
        ["depth"],
        {"cam_K": "2000 0 325.3 0 -500 242 0 0 1"},
        422,
        ["cam_K", "focal lengths", "fy -500"],
    ),
    "cam_K of focal length 1e-300": (
        ["rgb", "depth"],
        {**K_CENTRED, "cam_K": "1e-300 0 325 0 1e-300 242 0 0 1"},
        422,
        ["focal lengths"],
    ),
    "cam_K of focal length 1e300": (
        ["rgb"],
        {**K_CENTRED, "cam_K": "1e300 0 325.3 0 1e300 242 0 0 1"},
        422,
        ["focal lengths"],
    ),
    "cam_K of principal point 1e9": (
        ["rgb"],
        {**K_CENTRED, "cam_K": "572 0 1e9 0 573 242 0 0 1"},
        422,
        ["principal point"],
    ),
    "an empty .npy depth": (["empty float depth"], {}, 422, ["0 x 0 px", "too small"]),
    "a one-row .npy depth frame": (
        ["one-row float depth"],
        {**CAMERA, "cy": "0.5"},
        422,
        ["640 x 1 px", "too small"],
    ),
    "a one-column TIFF depth patch": (["one-column float TIFF"], {}, 422, ["1 x 640 px", "too small"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_each_bad_input_is_refused_with_what_to_do(client, images, case):
    names, form, status, words = CASES[case]
    files = {
        ("rgb" if n in ("rgb", "grey", "narrow patch") else "depth"): (f"{i}.png", images[n])
        for i, n in enumerate(names)
    }
    r = client.post("/recognize", files=files, data=form)
    assert r.status_code == status, r.text
    detail = r.json()["detail"]
    assert "\n" not in detail and all(w in detail for w in words), detail


def test_more_answers_drawn_than_asked_for_is_refused(client, images):
    r = client.post(
        "/recognize/draw", files={"rgb": ("f.png", images["rgb"])}, data={**CENTRED, "k": "2", "draw_k": "5"}
    )
    assert r.status_code == 422 and "draw_k: at most k (2)" in r.json()["detail"]


def test_a_drawing_refuses_what_an_answer_refuses(client, images):
    r = client.post("/recognize/draw", files={"depth": ("d.png", images["depth in 0.1 mm"])}, data=CAMERA)
    assert r.status_code == 422 and "depth_scale=0.1" in r.json()["detail"]
    r = client.post("/recognize/draw", files={"rgb": ("g.png", images["grey"])}, data=CENTRED)
    assert r.status_code == 422 and "greyscale" in r.json()["detail"]


def test_the_same_frames_in_the_right_units_are_answered(client, images):
    """The checks refuse what is wrong, not what is right: the example frame as it is, its depth in 0.1 mm
    with depth_scale 0.1, as float32 metres (.npy, as SDKs write it), and as float mm with depth_scale 1."""
    for files, form in (
        ({"depth": ("d.png", images["depth"])}, CAMERA),
        ({"depth": ("d.png", images["depth in 0.1 mm"])}, {**CAMERA, "depth_scale": "0.1"}),
        ({"rgb": ("f.png", images["rgb"])}, CENTRED),
        ({"depth": ("d.npy", images["float depth in m"])}, CAMERA),
        ({"depth": ("d.npy", images["float depth in mm"])}, {**CAMERA, "depth_scale": "1"}),
    ):
        r = client.post("/recognize", files=files, data=form)
        assert r.status_code == 200, r.text
