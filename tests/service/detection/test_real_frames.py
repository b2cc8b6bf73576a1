"""Finding the registered objects in real frames without being told where they are, with the shipped
models: the real Kinect frame (LM-O scene 2 frame 3, ../shared/data/lmo-depth) sent as RGB-D, and one
real colour frame, with LM-O's seven meshes registered through `POST /objects`. A detection is right when
it names an instance's object and its box overlaps the instance's visible or whole box by IoU >= 0.5 (as
`posedesc evaluate --protocol detect` counts)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_helpers import ROOT, created, service_settings, wait_ready

from index.data.bop import BopDataset
from index.geometry.pose_error import ADD_FRACTION, add, adi
from service.detection.merge import iou
from service.main import create_app
from service.settings import Settings
from service.threads import worker_pool

# registers the real LM-O objects and searches real frames whole: `make test`, not `make check`; the module's
# fixtures made once, on one worker (on two, each built the 30 s one)
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("real-frames")]

SHARED = ROOT.parent / "shared" / "data"
MODELS = ROOT / "models"


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    if not (SHARED / "lmo-depth" / "test" / "000002" / "depth" / "000003.png").is_file():
        pytest.skip(f"real depth not present at {SHARED / 'lmo-depth'}")
    if not (MODELS / "posedesc-objectness.onnx").is_file():
        pytest.skip(f"no shipped objectness model in {MODELS}")
    info = json.loads((SHARED / "lmo" / "models" / "models_info.json").read_text())
    with TestClient(create_app(service_settings(tmp_path_factory.mktemp("data"), MODELS, level=3))) as c:
        wait_ready(c)
        c.ids = {}
        for o in sorted(int(k) for k in info):
            path = SHARED / "lmo" / "models" / f"obj_{o:06d}.ply"
            symmetry = "180" if info[str(o)].get("symmetries_discrete") else "none"
            data = {"name": f"obj_{o}", "units": "mm", "symmetry": symmetry}
            r = c.post("/objects", files={"mesh": (path.name, path.read_bytes())}, data=data)
            c.ids[created(c, r, 300.0)["object_id"]] = o
        yield c


def right(client, root: Path, frame: int, detections: list[dict]) -> set[int]:
    """The instances (their index in the frame's ground truth) found by a right detection, at least half
    visible."""
    insts = [i for i in BopDataset(root).instances(2) if i.frame_id == frame]
    found: set[int] = set()
    for d in detections:
        obj = client.ids[d["best"]["object_id"]]
        for n, i in enumerate(insts):
            boxes = [
                (b[0], b[1], b[0] + b[2], b[1] + b[3]) for b in (i.bbox_visib, i.bbox_obj) if b is not None
            ]
            if i.obj_id == obj and n not in found and max(iou(d["box"], b) for b in boxes) >= 0.5:
                if i.visib_fract >= 0.5:
                    found.add(n)
                break
    return found


def camera(root: Path, frame: int) -> dict[str, str]:
    K = json.loads((root / "test" / "000002" / "scene_camera.json").read_text())[str(frame)]["cam_K"]
    return {"fx": str(K[0]), "fy": str(K[4]), "cx": str(K[2]), "cy": str(K[5])}


def test_the_real_kinect_frame_rgbd_without_a_centre(client):
    """The issue's target is 5 of the frame's 6 instances at least half visible; measured today: 4 (the
    can, the cat, the glue and the hole puncher; the driller lies on its side, its depth segment's centre
    25 px off, and the egg box, half hidden under a toy car, is named otherwise)."""
    root = SHARED / "lmo-depth"
    scene = root / "test" / "000002"
    files = {"rgb": ("f.png", (scene / "rgb" / "000003.png").read_bytes()),
             "depth": ("d.png", (scene / "depth" / "000003.png").read_bytes())}  # fmt: skip
    r = client.post("/recognize", files=files, data=camera(root, 3))
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["model"] == "posedesc-rgbd"
    found = right(client, root, 3, body["detections"])
    print("RGB-D, frame 3: right", len(found), "of 6; reported", len(body["detections"]))
    assert len(found) >= 4, body["detections"]


def test_a_real_colour_frame_without_a_centre(client):
    """Colour alone: the objectness network's proposals, each verified at its centre. Frame 224 (a
    validation frame): the bound is below what it finds today (printed)."""
    root = SHARED / "lmo"
    rgb = (root / "test" / "000002" / "rgb" / "000224.png").read_bytes()
    r = client.post("/recognize", files={"rgb": ("f.png", rgb)}, data=camera(root, 224))
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["model"] == "posedesc-rgb"
    found = right(client, root, 224, body["detections"])
    print("colour, frame 224: right", len(found), "of", 6, "; reported", len(body["detections"]))
    assert len(found) >= 2, body["detections"]
    for d in body["detections"]:
        t = d["best"]["t"]
        assert 300 < t[2] < 3000  # the distance estimated from colour alone is a table-top one
        # weighed by its colours (LM-O's meshes have them) and reported at the colour frames' floor
        assert d["colour_distance"] is not None and 0 <= d["colour_distance"] <= 2
        assert d["confidence"] >= Settings.model_fields["detect_rgb_floor"].default


def test_a_floor_gives_what_floor_0_gives_above_it(client):
    """A colour proposal scored under the floor is dropped before it is verified (`proposals.Propose`): its
    detection could not be reported. The answer must be the one of floor 0 cut at the floor, detection for
    detection."""
    root = SHARED / "lmo"
    rgb = (root / "test" / "000002" / "rgb" / "000243.png").read_bytes()

    def asked(floor: float) -> list[tuple]:
        data = {**camera(root, 243), "min_confidence": str(floor), "max_detections": "50"}
        r = client.post("/recognize", files={"rgb": ("f.png", rgb)}, data=data)
        assert r.status_code == 200, r.text
        return [(d["best"]["object_id"], round(d["confidence"], 6), d["box"]) for d in r.json()["detections"]]

    every, above = asked(0.0), asked(0.5)
    print("floor 0:", len(every), "detections; floor 0.5:", len(above))
    assert len(every) > len(above) > 0  # the frame has detections on both sides of the floor
    assert above == [x for x in every if x[1] >= 0.5]


def test_places_verified_side_by_side_answer_as_one_at_a_time(client):
    """`DETECT_THREADS` 2 (the default) verifies a frame's places two at a time: each place's answer must be
    the one it gets alone, in the same order, whatever finishes first."""
    root = SHARED / "lmo"
    rgb = (root / "test" / "000002" / "rgb" / "000248.png").read_bytes()
    state = client.app.state.posedesc
    assert state.settings.detect_threads == 2

    def asked() -> list[tuple]:
        data = {**camera(root, 248), "min_confidence": "0", "max_detections": "50"}
        r = client.post("/recognize", files={"rgb": ("f.png", rgb)}, data=data)
        assert r.status_code == 200, r.text
        return [
            (d["best"]["object_id"], d["confidence"], d["box"], d["best"]["R"])
            for d in r.json()["detections"]
        ]

    side_by_side = asked()
    two = state.verifier
    state.verifier = worker_pool(1, "verify-alone", 1)
    try:
        alone = asked()
    finally:
        state.verifier.shutdown(wait=True)
        state.verifier = two
    assert len(alone) >= 3 and side_by_side == alone


@pytest.fixture(scope="module")
def demo_only(tmp_path_factory):
    """The service as it starts by default: its four demo shapes registered, none of them in LM-O's frames."""
    if not (MODELS / "posedesc-objectness.onnx").is_file():
        pytest.skip(f"no shipped objectness model in {MODELS}")
    settings = service_settings(tmp_path_factory.mktemp("demo"), MODELS, level=3, demo_objects=True)
    with TestClient(create_app(settings)) as c:
        wait_ready(c, timeout=300.0)
        yield c


def test_real_colour_frames_of_objects_nobody_registered_give_almost_no_detections(demo_only):
    """Issue 36's false alarms: LM-O's objects are not the demo shapes, so every detection is false. The
    recognition names some demo shape on each real object; the colours at its pose say it is not there
    (`service.detection.agree`). Before that check: 2.05 detections a frame on the test frames."""
    root = SHARED / "lmo"
    found = 0
    for frame_id in (224, 243, 248, 254):  # validation frames
        rgb = (root / "test" / "000002" / "rgb" / f"{frame_id:06d}.png").read_bytes()
        r = demo_only.post("/recognize", files={"rgb": ("f.png", rgb)}, data=camera(root, frame_id))
        assert r.status_code == 200, r.text
        found += len(r.json()["detections"])
        print("demo shapes only, frame", frame_id, [d["confidence"] for d in r.json()["detections"]])
    assert found <= 2


def test_the_pose_fit_puts_the_kinect_frames_objects_within_add_s(client):
    """The issue's target: with the centre given (each instance's origin projected), at least 5 of the
    frame's 6 instances at least half visible within ADD(-S) < 0.1 d once the best answer is fitted to
    the real depth (ICP); 3 of them before. The egg box is named otherwise (see above)."""
    root = SHARED / "lmo-depth"
    scene = root / "test" / "000002"
    files = {"rgb": ("f.png", (scene / "rgb" / "000003.png").read_bytes()),
             "depth": ("d.png", (scene / "depth" / "000003.png").read_bytes())}  # fmt: skip
    dataset = BopDataset(root)
    within, fitted = [], 0
    for inst in dataset.instances(2):
        if inst.frame_id != 3 or inst.visib_fract < 0.5:
            continue
        u, v = inst.centre_uv
        r = client.post(
            "/recognize", files=files, data={**camera(root, 3), "u": str(u), "v": str(v), "k": "1"}
        )
        assert r.status_code == 200, r.text
        best = r.json()["matches"][0]
        fitted += best["refined"]
        if client.ids[best["object_id"]] != inst.obj_id:
            continue
        R, t = np.reshape(best["R"], (3, 3)), np.asarray(best["t"])
        points = np.asarray(dataset.mesh(inst.obj_id).vertices)
        symmetric = dataset.symmetry(inst.obj_id) != "none"
        error = (adi if symmetric else add)(R, t, inst.R, inst.t, points)
        if error < ADD_FRACTION * dataset.models_info[inst.obj_id]["diameter"]:
            within.append(inst.obj_id)
    print("RGB-D, frame 3, centre given: within ADD(-S) < 0.1 d:", within, "fitted:", fitted)
    assert fitted >= 5 and len(within) >= 5, within
