"""`service.inputs.camera`: the camera as OpenCV and BOP write it. `cam_K` gives the same answers as fx, fy, cx,
cy; a distorted frame is undistorted onto the same K (its colour, its depth, the centre sent with it), and
what is no camera is refused in one line."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_helpers import png, service_settings, wait_ready

from service.errors import ApiError
from service.inputs.camera import coefficients, intrinsics, undistorted, undistorted_point
from service.main import create_app

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
DIST = (-0.25, 0.08, 0.001, -0.0005, 0.0)  # a wide lens's barrel distortion


def distorted(clean: np.ndarray, interpolation: int) -> np.ndarray:
    """What a camera with DIST records of `clean` (the image of the same K without distortion)."""
    h, w = clean.shape[:2]
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 1, 2).astype(np.float64)
    where = cv2.undistortPoints(grid, K, np.array(DIST), P=K).reshape(h, w, 2).astype(np.float32)
    return cv2.remap(clean, where[..., 0], where[..., 1], interpolation)


def distort_point(u: float, v: float) -> tuple[float, float]:
    ray = np.linalg.inv(K) @ np.array([u, v, 1.0])
    p, _ = cv2.projectPoints(ray.reshape(1, 1, 3), np.zeros(3), np.zeros(3), K, np.array(DIST))
    return float(p[0, 0, 0]), float(p[0, 0, 1])


def test_a_distorted_frame_is_undistorted_onto_the_same_camera():
    rng = np.random.default_rng(0)
    clean = cv2.resize(rng.integers(0, 256, (48, 64, 3), np.uint8), (640, 480), interpolation=cv2.INTER_CUBIC)
    depth = np.full((480, 640), 800.0, np.float32)
    depth[200:280, 300:380] = 600.0  # a box before a wall
    rgb, d = undistorted(distorted(clean, cv2.INTER_LINEAR), distorted(depth, cv2.INTER_NEAREST), K, DIST)
    assert rgb is not None and d is not None
    inner = (slice(80, 400), slice(100, 540))
    assert np.abs(rgb[inner].astype(float) - clean[inner]).mean() < 6  # two resamplings of a smooth texture
    assert set(np.unique(d[inner])) <= {600.0, 800.0}  # nearest: no depth between the two surfaces
    assert np.mean(d[inner] == depth[inner]) > 0.99
    for u, v in ((325.3, 242.0), (100.0, 80.0), (600.0, 420.0)):
        assert undistorted_point(*distort_point(u, v), K, DIST) == pytest.approx((u, v), abs=0.05)


@pytest.mark.parametrize(
    ("text", "said"),
    [
        ("572.4 0 325.3 0 573.6 242 0 0", "9 numbers"),
        ("572.4 5 325.3 0 573.6 242 0 0 1", "no skew"),
        ("572.4 0 325.3 0 573.6 242 0 1 1", "no skew"),
        ("572.4 0 x 0 573.6 242 0 0 1", "not a list of numbers"),
        ("572.4 0 nan 0 573.6 242 0 0 1", "finite"),
    ],
)
def test_what_is_no_camera_matrix_is_refused(text, said):
    with pytest.raises(ApiError) as e:
        intrinsics(text)
    assert e.value.status_code == 422 and said in e.value.detail


def test_cam_k_and_coefficients_read_as_opencv_and_bop_write_them():
    assert intrinsics("[572.4, 0.0, 325.3, 0.0, 573.6, 242.0, 0.0, 0.0, 1.0]") == (572.4, 573.6, 325.3, 242.0)
    assert coefficients("0 0 0 0 0") is None  # nothing to undo
    assert coefficients("-0.25,0.08,0.001,-0.0005") == (-0.25, 0.08, 0.001, -0.0005)
    with pytest.raises(ApiError, match="4, 5, 8, 12 or 14"):
        coefficients("0.1 0.2 0.3")


@pytest.fixture(scope="module")
def client(tmp_path_factory, posedesc_models, t_shape):
    from service_helpers import register

    app = create_app(service_settings(tmp_path_factory.mktemp("camera") / "data", posedesc_models, level=0))
    with TestClient(app) as c:
        wait_ready(c)
        register(c, t_shape, "T")
        yield c


def test_the_api_takes_cam_k_and_undistorts_what_it_is_sent(client, renderer, t_shape):
    from service_helpers import frame

    from index.geometry.pose import View

    uv = (300.0, 230.0)
    rgb, _ = frame(renderer, t_shape, View(30.0, 40.0, 0.0, 500.0), uv)
    camera = {"fx": "572.4", "fy": "573.6", "cx": "325.3", "cy": "242.0"}
    cam_k = "572.4 0 325.3 0 573.6 242.0 0 0 1"
    form = {"u": str(uv[0]), "v": str(uv[1]), "distance_mm": "500", "k": "3"}
    files = {"rgb": ("f.png", png(rgb))}
    by_fields = client.post("/recognize", files=files, data={**camera, **form}).json()
    by_k = client.post("/recognize", files=files, data={"cam_K": cam_k, **form}).json()
    assert by_k["matches"] == by_fields["matches"]
    # the same frame as a distorted lens records it, with the centre where that lens puts it
    du, dv = distort_point(*uv)
    bent = {"rgb": ("d.png", png(distorted(rgb, cv2.INTER_LINEAR)))}
    dist = " ".join(map(str, DIST))
    r = client.post(
        "/recognize",
        files=bent,
        data={"cam_K": cam_k, "dist_coeffs": dist, **form, "u": str(du), "v": str(dv)},
    )
    assert r.status_code == 200, r.text
    undone = r.json()["matches"][0]
    assert undone["object_id"] == by_fields["matches"][0]["object_id"]
    assert undone["u"] == pytest.approx(uv[0], abs=1.0) and undone["v"] == pytest.approx(uv[1], abs=1.0)
    for data, said in (
        ({"cam_K": cam_k, **camera, **form}, "send the camera once"),
        ({"dist_coeffs": dist}, "send its cam_K"),
        ({"cam_K": "1 2 3", **form}, "9 numbers"),
    ):
        r = client.post("/recognize", files=files, data=data)
        assert r.status_code == 422 and said in r.json()["detail"], r.text
