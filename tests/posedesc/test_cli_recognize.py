"""`posedesc recognize` as a user runs it (a real subprocess, the shipped models): image files answered as
POST /recognize answers them, from a data dir `posedesc build-index` made; the object at a centre, every
object of a frame, a BOP folder with its scene_camera.json, and bad input in one line."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MODELS = ROOT / "models"
PART = ROOT / "service" / "examples" / "part.ply"

pytestmark = pytest.mark.slow  # a registration, renders and three recognitions


def posedesc(*args: str) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).parent / "posedesc"  # the console script, as a user runs it
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=600, cwd=ROOT)


@pytest.fixture(scope="module")
def registered(tmp_path_factory) -> tuple[Path, Path]:
    """A data dir holding the example part, and query frames of it (`posedesc render --patches`)."""
    if not (MODELS / "posedesc-rgb.onnx").is_file():
        pytest.skip(f"no shipped models in {MODELS}")
    tmp = tmp_path_factory.mktemp("recognize")
    (tmp / "meshes").mkdir()
    (tmp / "meshes" / "part.ply").write_bytes(PART.read_bytes())
    done = posedesc(
        "build-index",
        "--meshes",
        str(tmp / "meshes"),
        "--data-dir",
        str(tmp / "data"),
        "--units",
        "mm",
        "--level",
        "1",
    )
    assert done.returncode == 0, done.stderr
    done = posedesc("render", str(PART), "--patches", str(tmp / "queries"))
    assert done.returncode == 0, done.stderr
    return tmp / "data", tmp / "queries"


def test_the_object_at_a_centre_and_every_object_of_a_frame(registered, tmp_path):
    data, queries = registered
    q = json.loads((queries / "query-00.json").read_text())
    form = {k: str(v) for k, v in q["form"].items()}
    frame = queries / "query-00-rgb.png"
    at = [f"--{k.replace('_', '-')}={form[k]}" for k in ("fx", "fy", "cx", "cy", "u", "v", "distance_mm")]
    done = posedesc("recognize", str(frame), "--data-dir", str(data), "--out", str(tmp_path / "a"), *at)
    assert done.returncode == 0, done.stderr
    answer = json.loads((tmp_path / "a" / "query-00-rgb.json").read_text())
    assert answer["best"]["name"] == "part" and len(answer["matches"]) == 5
    assert (tmp_path / "a" / "query-00-rgb-answers.png").stat().st_size > 1000
    # no centre: the frame searched whole, with its depth
    camera = at[:4]
    depth = str(queries / "query-00-depth.png")
    done = posedesc(
        "recognize",
        str(frame),
        "--depth",
        depth,
        "--data-dir",
        str(data),
        "--out",
        str(tmp_path / "b"),
        *camera,
    )
    assert done.returncode == 0, done.stderr
    whole = json.loads((tmp_path / "b" / "query-00-rgb.json").read_text())
    assert "detections" in whole and all(d["best"]["name"] == "part" for d in whole["detections"])


def test_a_bop_folder_with_its_cameras_and_a_frame_it_cannot_answer(registered, tmp_path):
    data, queries = registered
    q = json.loads((queries / "query-00.json").read_text())
    scene = tmp_path / "scene"
    (scene / "rgb").mkdir(parents=True)
    (scene / "depth").mkdir()
    for i in (1, 2):
        (scene / "rgb" / f"{i:06d}.png").write_bytes((queries / f"query-0{i - 1}-rgb.png").read_bytes())
        (scene / "depth" / f"{i:06d}.png").write_bytes((queries / f"query-0{i - 1}-depth.png").read_bytes())
    f = q["form"]
    K = [f["fx"], 0, f["cx"], 0, f["fy"], f["cy"], 0, 0, 1]
    cameras = {
        "1": {"cam_K": K, "depth_scale": 1.0},
        "2": {"cam_K": K, "depth_scale": 10.0},
    }  # 2: wrong units
    (scene / "scene_camera.json").write_text(json.dumps(cameras))
    done = posedesc(
        "recognize",
        str(scene),
        "--camera",
        str(scene / "scene_camera.json"),
        "--data-dir",
        str(data),
        "--out",
        str(tmp_path / "out"),
        "--no-draw",
    )
    assert done.returncode == 1, done.stderr  # one frame failed, the other answered
    assert (tmp_path / "out" / "000001.json").is_file() and not (tmp_path / "out" / "000002.json").exists()
    assert "000002.png: " in done.stderr and "depth_scale" in done.stderr
    assert "1 of 2 frames answered" in done.stdout


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--fx", "500"], "all of --fx, --fy, --cx and --cy"),
        ([], "give its camera"),
        (["--fx", "500", "--fy", "500", "--cx", "320", "--cy", "99999"], "cy = 99999"),
    ],
)
def test_bad_input_is_one_line(registered, tmp_path, args, said):
    data, queries = registered
    done = posedesc(
        "recognize", str(queries / "query-00-rgb.png"), "--data-dir", str(data), "--out", str(tmp_path), *args
    )
    assert done.returncode == 2 and said in done.stderr and "Traceback" not in done.stderr, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


def test_one_frame_in_a_terminal_says_what_it_loads_and_answers(registered, tmp_path):
    """In a terminal one frame is never answered in silence: what is loaded, what is registered, which
    frame is being answered (to a pipe, stderr stays for the one-line error alone)."""
    import os
    import pty

    data, queries = registered
    q = json.loads((queries / "query-00.json").read_text())
    at = [
        f"--{k.replace('_', '-')}={q['form'][k]}" for k in ("fx", "fy", "cx", "cy", "u", "v", "distance_mm")
    ]
    exe = Path(sys.executable).parent / "posedesc"
    frame = queries / "query-00-rgb.png"
    args = [
        str(exe),
        "recognize",
        str(frame),
        "--data-dir",
        str(data),
        "--out",
        str(tmp_path),
        "--no-draw",
        *at,
    ]
    controller, terminal = pty.openpty()
    done = subprocess.run(args, stderr=terminal, stdout=subprocess.PIPE, cwd=ROOT, timeout=600)
    os.close(terminal)
    said = b""
    while True:
        try:
            chunk = os.read(controller, 4096)
        except OSError:
            break
        if not chunk:
            break
        said += chunk
    os.close(controller)
    text = said.decode()
    assert done.returncode == 0
    assert "loading the models of" in text and "1 objects registered: part" in text
    assert f"answering {frame} ..." in text


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--fx", "nan", "--fy", "500", "--cx", "320", "--cy", "240"], "--fx: nan: a finite number from 1"),
        (["--fx", "-572", "--fy", "500", "--cx", "320", "--cy", "240"], "--fx: -572: a finite number from 1"),
        (["--u", "10", "--v", "10", "--distance-mm", "inf"], "--distance-mm: inf: a finite number over 0"),
        (["--k", "0"], "--k: 0: at least 1"),
        (["--max-detections", "-1"], "--max-detections: -1: at least 1"),
        (["--min-confidence", "nan"], "--min-confidence: nan"),
    ],
)
def test_impossible_numbers_are_refused_before_anything_runs(registered, tmp_path, args, said):
    """A fuzzing of the CLI (2026-12-08) had these answered, exit 0: nothing found, a wrong pose, invalid JSON."""
    data, queries = registered
    done = posedesc(
        "recognize", str(queries / "query-00-rgb.png"), "--data-dir", str(data), "--out", str(tmp_path), *args
    )
    assert done.returncode == 2 and said in done.stderr and "Traceback" not in done.stderr, done.stderr


def test_a_file_that_is_no_image_fails_its_frame_and_the_others_are_answered(registered, tmp_path):
    """An empty PNG in a folder of frames stopped the whole batch with a traceback (the 16-bit check opened
    it first); now it fails alone, as a frame in the wrong units does."""
    data, queries = registered
    folder = tmp_path / "frames"
    folder.mkdir()
    (folder / "a.png").write_bytes((queries / "query-00-depth.png").read_bytes())
    (folder / "b.png").write_bytes(b"")
    q = json.loads((queries / "query-00.json").read_text())["form"]
    camera = [f"--{k}={q[k]}" for k in ("fx", "fy", "cx", "cy")]
    done = posedesc(
        "recognize", str(folder), "--data-dir", str(data), "--out", str(tmp_path / "o"), "--no-draw", *camera
    )
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    assert "b.png: " in done.stderr and "1 of 2 frames answered" in done.stdout


def _templates(data: Path) -> dict[str, int]:
    import sqlite3

    db = sqlite3.connect(data / "store.sqlite")
    try:
        return dict(db.execute("SELECT model, count(*) FROM templates GROUP BY model").fetchall())
    finally:
        db.close()


def test_other_models_never_drop_a_data_dirs_templates(registered, tmp_path):
    """`recognize` or `build-index` with a models folder whose depth model is another file: the store would
    drop that model's templates on opening (for `serve` to make again at its start); a fuzzing of the CLI
    (2026-12-08) found a data dir so emptied of its depth templates, and the next recognition finding nothing,
    exit 0. Both now refuse in one line and leave the data dir as it was."""
    import shutil

    data, queries = registered
    copy = tmp_path / "data"
    shutil.copytree(data, copy)
    other = tmp_path / "models"
    shutil.copytree(MODELS, other, ignore=shutil.ignore_patterns("experiments", "*.md", "baseline"))
    shutil.copy(MODELS / "experiments" / "posedesc-depth-upright.onnx", other / "posedesc-depth.onnx")
    before = _templates(copy)
    frame = queries / "query-00-depth.png"
    q = json.loads((queries / "query-00.json").read_text())["form"]
    camera = [f"--{k}={q[k]}" for k in ("fx", "fy", "cx", "cy")]
    done = posedesc("recognize", str(frame), "--data-dir", str(copy), "--models", str(other), *camera)
    assert done.returncode == 2 and "were made with other model files" in done.stderr, done.stderr
    assert "depth" in done.stderr and "Traceback" not in done.stderr
    meshes = tmp_path / "meshes"
    meshes.mkdir()
    (meshes / "again.ply").write_bytes(PART.read_bytes())
    done = posedesc("build-index", "--meshes", str(meshes), "--data-dir", str(copy), "--models", str(other))
    assert done.returncode == 2 and "were made with other model files" in done.stderr, done.stderr
    assert _templates(copy) == before


def test_a_damaged_store_is_one_line(registered, tmp_path):
    import shutil

    data, queries = registered
    copy = tmp_path / "data"
    shutil.copytree(data, copy)
    with open(copy / "store.sqlite", "r+b") as f:
        f.write(b"X" * 100)
    q = json.loads((queries / "query-00.json").read_text())["form"]
    camera = [f"--{k}={q[k]}" for k in ("fx", "fy", "cx", "cy")]
    done = posedesc("recognize", str(queries / "query-00-depth.png"), "--data-dir", str(copy), *camera)
    assert done.returncode == 2 and "not a usable store" in done.stderr and "Traceback" not in done.stderr, (
        done.stderr
    )
