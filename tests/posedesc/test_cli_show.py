"""`posedesc show` as a user runs it (a real subprocess) on an answer a real service gave, its meshes read
from that service's data dir."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from index.draw import PATCH_DRAW_PX
from index.geometry.pose import View, view_to_pose

ROOT = Path(__file__).resolve().parents[2]
K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
VIEWS = ((View(40.0, 30.0, 0.0, 600.0), (220.0, 250.0)), (View(130.0, 50.0, 30.0, 700.0), (450.0, 200.0)))


def posedesc(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).parent / "posedesc"
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=300, cwd=cwd)


def intrinsics() -> list[str]:
    return ["--fx", "572.4", "--fy", "573.6", "--cx", "325.3", "--cy", "242.0"]


@pytest.fixture(scope="module")
def answered(tmp_path_factory, renderer, l_shape):
    """A data dir with the L registered, a frame with two Ls and the service's answer for each."""
    from fastapi.testclient import TestClient

    from service.main import create_app
    from service.settings import Settings

    tmp = tmp_path_factory.mktemp("show")
    scene = []
    for view, uv in VIEWS:
        R, t = view_to_pose(view, np.linalg.inv(K) @ np.array([uv[0], uv[1], 1.0]))
        scene.append((l_shape, R, t))
    rgb, _ = renderer.render_frame(scene, K, 640, 480)
    frame = tmp / "frame.png"
    cv2.imwrite(str(frame), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    settings = Settings(  # answered at once however busy the machine (no test may depend on speed)
        data_dir=tmp / "data",
        models_dir=ROOT / "models",
        demo_objects=False,
        level=1,
        reject_above="off",
        sync_seconds=300.0,
    )
    answers = []
    with TestClient(create_app(settings)) as c:
        while c.get("/readyz").status_code != 200:
            time.sleep(0.1)
        r = c.post(
            "/objects", files={"mesh": ("ell.ply", l_shape.export(file_type="ply"))}, data={"name": "ell"}
        )
        assert r.status_code == 201, r.text
        for i, (view, uv) in enumerate(VIEWS):
            form = {
                "fx": "572.4",
                "fy": "573.6",
                "cx": "325.3",
                "cy": "242.0",
                "u": str(uv[0]),
                "v": str(uv[1]),
            }
            files = {"rgb": ("f.png", frame.read_bytes())}
            answer = c.post("/recognize", files=files, data={**form, "distance_mm": str(view.distance)})
            assert answer.status_code == 200, answer.text
            path = tmp / f"answer-{i}.json"
            path.write_text(answer.text)
            answers.append(path)
    return frame, answers, tmp / "data", rgb


def test_show_draws_every_answer_on_the_frame(answered, tmp_path):
    frame, answers, data, rgb = answered
    out = tmp_path / "drawn.png"
    r = posedesc(
        "show", str(frame), *map(str, answers), "--data-dir", str(data), "--out", str(out), *intrinsics()
    )
    assert r.returncode == 0, r.stderr
    drawn = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    assert drawn.shape == rgb.shape
    changed = (drawn != rgb).any(axis=2)
    for _, (u, v) in VIEWS:  # each object's place drawn on
        assert changed[int(v) - 20 : int(v) + 20, int(u) - 20 : int(u) + 20].mean() > 0.5
    only_first = tmp_path / "one.png"
    r = posedesc(
        "show", str(frame), str(answers[0]), "--data-dir", str(data), "--out", str(only_first), *intrinsics()
    )
    one = cv2.imread(str(only_first))
    assert r.returncode == 0 and (one != cv2.imread(str(out))).any()


def test_show_draws_a_patch_upscaled_into_the_current_folder_never_the_inputs(answered, tmp_path):
    frame, answers, data, rgb = answered
    (tmp_path / "inputs").mkdir()
    (tmp_path / "here").mkdir()
    patch = tmp_path / "inputs" / "patch.png"
    cv2.imwrite(str(patch), np.full((64, 64, 3), 90, np.uint8))
    r = posedesc("show", str(patch), str(answers[0]), "--data-dir", str(data), cwd=tmp_path / "here")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "inputs").iterdir()) == ["patch.png"]  # left as it was
    drawn = cv2.imread(str(tmp_path / "here" / "patch-answers.png"))
    assert drawn.shape == (PATCH_DRAW_PX, PATCH_DRAW_PX, 3) and (drawn != 90).any()


def one_line_error(r: subprocess.CompletedProcess, text: str) -> None:
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and text in r.stderr, r.stderr


def test_show_refuses_a_missing_object_in_one_line(answered, tmp_path):
    frame, answers, data, _ = answered
    answer = json.loads(answers[0].read_text())
    answer["matches"][0]["object_id"] = 999
    gone = tmp_path / "gone.json"
    gone.write_text(json.dumps(answer))
    out = tmp_path / "x.png"
    r = posedesc("show", str(frame), str(gone), "--data-dir", str(data), "--out", str(out), *intrinsics())
    one_line_error(r, "object 999 (ell) has no mesh in")
    assert not out.exists()


# a subprocess per bad input: ~5 s
@pytest.mark.slow
def test_show_refuses_bad_input_in_one_line(answered, tmp_path):
    frame, answers, data, _ = answered
    args = ["--data-dir", str(data), *intrinsics()]
    one_line_error(posedesc("show", str(tmp_path / "no.png"), str(answers[0]), *args), "no such file")
    one_line_error(posedesc("show", str(frame), str(tmp_path / "no.json"), *args), "no such file")
    not_answer = tmp_path / "a.json"
    not_answer.write_text('{"detail": "bad"}')
    one_line_error(posedesc("show", str(frame), str(not_answer), *args), "not a /recognize answer")
    r = posedesc("show", str(frame), str(answers[0]), "--data-dir", str(tmp_path / "nodata"), *intrinsics())
    one_line_error(r, "no such data dir")
    one_line_error(
        posedesc("show", str(frame), str(answers[0]), "--data-dir", str(data)), "not a square patch"
    )
    r = posedesc("show", str(frame), str(answers[0]), "--data-dir", str(data), "--fx", "500")
    one_line_error(r, "needs all of --fx, --fy, --cx and --cy")


def test_a_whole_frames_answer_draws_every_object_found(tmp_path):
    """`posedesc show` on a frame searched whole: each detection's best answers, not only the first's."""
    from posedesc.commands.show import read_answer

    def match(oid: int, name: str) -> dict:
        return {"object_id": oid, "name": name, "confidence": 0.9, "R": np.eye(3).tolist(), "t": [0, 0, 600]}

    found = [{"matches": [match(1, "a"), match(2, "b")]}, {"matches": [match(3, "c")]}]
    path = tmp_path / "answer.json"
    path.write_text(
        json.dumps({"best": found[0]["matches"][0], "matches": found[0]["matches"], "detections": found})
    )
    assert [oid for oid, _ in read_answer(path, 1)] == [1, 3]
    assert [oid for oid, _ in read_answer(path, 2)] == [1, 2, 3]
    path.write_text(json.dumps({"best": None, "matches": [match(4, "d")], "reason": "unknown"}))
    (only,) = read_answer(path, 1)
    assert only[0] == 4 and only[1].rejected
