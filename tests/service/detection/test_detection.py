"""`POST /recognize` with a whole frame and no centre: every registered object found in it
(`service.detection`). Errors with the test models (no objectness model); finding objects in a rendered
depth frame and in a colour frame with the shipped models."""

from __future__ import annotations

import numpy as np
import pytest
from coco_rle import decode
from fastapi.testclient import TestClient
from service_helpers import K, depth_png, frame, png, register, service_settings, wait_ready

from index.geometry.boxes import iou
from index.geometry.pose import View
from service.main import create_app

VIEW = View(azimuth=37.0, elevation=28.0, inplane=0.0, distance=600.0)
UV = (400.0, 220.0)
CAMERA = {"fx": str(K[0, 0]), "fy": str(K[1, 1]), "cx": str(K[0, 2]), "cy": str(K[1, 2])}


@pytest.fixture(scope="module")
def client(tmp_path_factory, posedesc_models, l_shape):
    with TestClient(create_app(service_settings(tmp_path_factory.mktemp("data"), posedesc_models))) as c:
        wait_ready(c)
        c.ids = {"L": register(c, l_shape, "L")["object_id"]}
        yield c


@pytest.fixture(scope="module")
def l_frame(renderer, l_shape):
    return frame(renderer, l_shape, VIEW, UV, wall_mm=1500.0)


def test_a_colour_frame_without_an_objectness_model_says_what_to_send(client, l_frame):
    r = client.post("/recognize", files={"rgb": ("f.png", png(l_frame[0]))}, data=CAMERA)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert "objectness" in detail and "send u and v" in detail


def test_a_frame_without_its_whole_camera_names_what_is_missing(client, l_frame):
    r = client.post("/recognize", files={"rgb": ("f.png", png(l_frame[0]))}, data={"fx": "572.4"})
    assert r.status_code == 422, r.text
    assert "missing: fy, cx, cy" in r.json()["detail"]


def test_a_distance_without_a_centre_is_refused(client, l_frame):
    data = {**CAMERA, "distance_mm": "600"}
    r = client.post("/recognize", files={"depth": ("d.png", depth_png(l_frame[1]))}, data=data)
    assert r.status_code == 422, r.text
    assert "send u and v" in r.json()["detail"]


@pytest.mark.parametrize("field, value", [("max_detections", "0"), ("min_confidence", "1.5")])
def test_detection_fields_out_of_range_are_refused(client, l_frame, field, value):
    r = client.post(
        "/recognize", files={"depth": ("d.png", depth_png(l_frame[1]))}, data={**CAMERA, field: value}
    )
    assert r.status_code == 422, r.text
    assert field in r.text


def test_a_depth_frame_is_searched_whole(client, l_frame):
    """The object before a wall, found from depth alone: its detection at its centre, its box around it;
    the top-level answer is the first detection's. The test models are untrained: the floor is 0, so
    what is found is reported whatever its confidence."""
    data = {**CAMERA, "min_confidence": "0", "k": "2"}
    r = client.post("/recognize", files={"depth": ("d.png", depth_png(l_frame[1]))}, data=data)
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["model"] == "posedesc-depth"
    dets = body["detections"]
    assert dets, body
    near = [x for x in dets if np.hypot(x["u"] - UV[0], x["v"] - UV[1]) < 25]
    assert near, [(x["u"], x["v"]) for x in dets]
    x = near[0]
    assert x["best"]["name"] == "L" and len(x["matches"]) <= 2
    x0, y0, x1, y1 = x["box"]
    assert x0 < UV[0] < x1 and y0 < UV[1] < y1
    assert body["best"] == dets[0]["best"] and body["matches"] == dets[0]["matches"]
    assert {"decode", "propose", "verify", "merge", "report", "mask", "total"} <= set(body["timings_ms"])
    # its mask: the mesh at the answered pose, as COCO's RLE, inside its box and over its centre
    mask = decode(x["mask"])
    assert x["mask"]["size"] == [480, 640] and mask.sum() > 100
    rows, cols = np.nonzero(mask)
    assert x0 - 1 <= cols.min() and cols.max() <= x1 + 1 and y0 - 1 <= rows.min() and rows.max() <= y1 + 1


def failures(client, stage: str) -> float:
    for line in client.get("/metrics").text.splitlines():
        if line.startswith(f'posedesc_pipeline_failures_total{{stage="{stage}"}}'):
            return float(line.split()[-1])
    return 0.0


def test_a_verification_that_fails_is_counted_and_reports_nothing(client, l_frame, monkeypatch):
    """A refusal of a query the service made itself is a failure, not "nothing there": logged, counted in
    /metrics, and the proposal it concerns is not reported (it never widens what is)."""
    import service.pipeline as pipeline
    from service.errors import ApiError

    def broken(self, *args, **kwargs):
        raise ApiError(422, "a fault injected into the verification")

    before = failures(client, "screen") + failures(client, "verify")
    monkeypatch.setattr(pipeline.Pipeline, "__call__", broken)
    data = {**CAMERA, "min_confidence": "0"}
    r = client.post("/recognize", files={"depth": ("d.png", depth_png(l_frame[1]))}, data=data)
    assert r.status_code == 200, r.text
    assert r.json()["detections"] == []
    # (a depth segment is screened first: the screening's failure is the first counted)
    assert failures(client, "screen") + failures(client, "verify") > before


def test_a_frame_with_a_centre_has_no_detections(client, l_frame):
    data = {**CAMERA, "u": str(UV[0]), "v": str(UV[1])}
    r = client.post("/recognize", files={"depth": ("d.png", depth_png(l_frame[1]))}, data=data)
    assert r.status_code == 200, r.text
    assert r.json()["detections"] is None


def test_iou():
    assert iou((0, 0, 10, 10), (0, 0, 10, 10)) == 1.0
    assert iou((0, 0, 10, 10), (10, 0, 20, 10)) == 0.0
    assert iou((0, 0, 10, 10), (5, 0, 15, 10)) == pytest.approx(50 / 150)


def test_the_objectness_network_is_beside_the_models_unless_a_setting_says_where(tmp_path):
    from index.features.objectness import OBJECTNESS_FILE
    from service.settings import Settings
    from service.state import colour_proposals, objectness_path

    beside = Settings(data_dir=tmp_path, models_dir=tmp_path / "m")
    assert objectness_path(beside) == tmp_path / "m" / OBJECTNESS_FILE
    elsewhere = Settings(data_dir=tmp_path, models_dir=tmp_path / "m", objectness_model=tmp_path / "o.onnx")
    assert objectness_path(elsewhere) == tmp_path / "o.onnx"
    assert colour_proposals(objectness_path(elsewhere), 1) is None  # no file there: colour needs u and v


def test_the_objectness_network_runs_at_the_levels_the_settings_give():
    """`POSEDESC_OBJECTNESS_LEVELS`: the frame is searched at those scales only. At scale 1 alone the network
    sees windows about its reference size (64 px, within a factor 1.6 either way: its head knows no others);
    at a quarter, four times as large; unset, the model's own nine levels cover both."""
    from service_helpers import ROOT

    from index.features.objectness import OBJECTNESS_FILE
    from service.settings import Settings
    from service.state import colour_proposals

    rgb = np.random.default_rng(0).integers(0, 255, (480, 640, 3), np.uint8)
    rgb[150:330, 250:430] = (200, 60, 40)  # a block of colour for something to propose
    path = ROOT / "models" / OBJECTNESS_FILE
    windows = {}
    for levels in ([1.0], [0.25], None):
        colour = colour_proposals(path, 1, levels)
        assert colour is not None
        windows[str(levels)] = [p.window_px for p in colour(rgb, 50)]
    assert windows["[1.0]"] and all(30 < w < 110 for w in windows["[1.0]"])
    assert windows["[0.25]"] and all(120 < w < 440 for w in windows["[0.25]"])
    assert Settings().objectness_levels == [1.0, 0.7071, 0.5, 0.3536, 0.25]
    assert min(windows["None"]) < 110 and max(windows["None"]) > 120


def test_a_detection_through_the_table_is_dropped(client, renderer, l_shape):
    """The support check (`service.detection.stand`) on the L standing on a table, seen from 900 mm at 40
    degrees down: the L at its pose stands; the same answer moved 80 mm down through the table is dropped;
    a frame with no table found keeps both."""
    from dataclasses import replace

    from index.geometry.sensor import plane_depth, support_plane
    from index.refine.fit import Fit
    from index.store import Match
    from service.detection.depth_segments import depth_scene
    from service.detection.found import Detection, Frame, Proposal
    from service.detection.stand import SUNK_SHARE, Stand
    from service.pipeline.answer import Result

    tilt = np.deg2rad(40)
    R = np.array([[1, 0, 0], [0, -np.sin(tilt), -np.cos(tilt)], [0, np.cos(tilt), -np.sin(tilt)]])
    table_t = np.array([0.0, 0.0, 900.0])
    t = R @ np.array([0.0, 0.0, -l_shape.bounds[0][2]]) + table_t  # its lowest face on the table
    n, d = support_plane(R, table_t, 0.0)
    _, obj = renderer.render_frame([(l_shape, R, t)], K, 640, 480)
    depth = np.where(obj > 0, obj, plane_depth(K, n, d, (480, 640))).astype(np.float32)
    support = depth_scene(depth, K).support
    assert support is not None

    def found(t_at: np.ndarray) -> Detection:
        match = Match(client.ids["L"], "L", 0.0, 0.0, 0.0, 0.1)
        fit = Fit(R, t_at, 0.9, 0.5, 5, True)
        result = Result("posedesc-depth", [match], {}, t_at / np.linalg.norm(t_at), 900.0, fits=[fit])
        return Detection(
            0.0, 0.0, (0.0, 0.0, 10.0, 10.0), 0.9, result, Proposal(0, 0, None, (0, 0, 1, 1), 1, "depth")
        )

    standing, sunk = found(t), found(t - 80.0 * R[:, 2])
    state = client.app.state.posedesc
    frame = Frame(None, None, K, state.store.snapshot, 0.0, support=support, detections=(standing, sunk))
    stand = Stand.build(state)
    assert stand.share == SUNK_SHARE
    assert stand(frame).detections == (standing,)
    assert stand(replace(frame, support=None)).detections == (standing, sunk)
    assert Stand(state, 1.0)(frame).detections == (standing, sunk)  # a share of 1: never dropped
