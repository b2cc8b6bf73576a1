"""The service protocol scored the BOP way (`evaluation.bop.scores`): the assembly on hand-made instances,
and `posedesc evaluate --protocol service --bop-csv` on two real LM-O frames with the shipped rgb model; the
detect protocol's matching of several scored estimates an image (`detections_block`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from evaluation.bop.csv import Estimate, read_bop_csv
from evaluation.bop.recall import bop_recall
from evaluation.bop.scores import (
    MAX_POINTS,
    Best,
    bop_block,
    detections_block,
    estimates,
    model_points,
    object_model,
)
from index.data.bop import Instance
from index.geometry.pose import View, view_to_pose
from posedesc.cli import main

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
ROOT = Path(__file__).resolve().parents[3]
RGB_MODEL = ROOT / "models" / "posedesc-rgb.onnx"


def instance(obj_id: int, frame_id: int, view: View, visib: float = 0.9) -> Instance:
    R, t = view_to_pose(view)
    return Instance(2, frame_id, 0, obj_id, R, t, K, None, None, 1.0, visib, None)


def guess(inst: Instance, score: float, obj_id: int | None = None, shift_mm: float = 0.0) -> Estimate:
    """An estimate of `inst`'s pose (`shift_mm` off along x), naming `obj_id` (default: its own)."""
    t = inst.t + np.array([shift_mm, 0.0, 0.0])
    return Estimate(inst.scene_id, inst.frame_id, inst.obj_id if obj_id is None else obj_id, score, inst.R, t)


@pytest.fixture
def models():
    box = trimesh.creation.box(extents=[60, 40, 20])
    info = {"diameter": float(np.linalg.norm([60, 40, 20]))}
    return {1: object_model(info, box), 2: object_model({**info, "symmetries_discrete": [np.eye(4)]}, box)}


def test_a_perfect_answer_scores_ar_1_and_a_missing_one_0(models):
    targets = [instance(1, 0, View(30, 40, 10, 700)), instance(2, 0, View(100, 20, -30, 900))]
    perfect = [Best(i.obj_id, i.R, i.t, 0.9, 0.1) for i in targets]
    b = bop_block(targets, perfect, models, 640, 0.5)
    assert b["ar"] == b["ar_mssd"] == b["ar_mspd"] == 1.0 and b["ar_vsd"] is None
    assert b["recall_add_s"] == b["recall_5deg_5cm"] == 1.0 and b["n_estimated"] == 2
    assert [p["add_kind"] for p in b["per_instance"]] == ["ADD", "ADD-S"]
    assert all(p[e] == pytest.approx(0.0, abs=1e-4) for p in b["per_instance"] for e in ("mssd", "te", "re"))
    # rejected (None) and another object named: no estimate of the target, wrong at every threshold
    wrong = [None, Best(1, targets[1].R, targets[1].t, None, 0.1)]
    b = bop_block(targets, wrong, models, 640, 0.5)
    assert b["ar"] == b["recall_add_s"] == b["recall_5deg_5cm"] == 0.0 and b["n_estimated"] == 0
    assert b["per_instance"][1]["mssd"] is None and b["per_instance"][1]["answer_obj_id"] == 1


def test_half_right_gives_half_and_the_rows_skip_rejected(models):
    targets = [instance(1, 0, View(30, 40, 10, 700)), instance(1, 5, View(30, 40, 10, 700))]
    R, t = targets[0].R, targets[0].t
    shifted = Best(1, R, t + np.array([0.0, 0.0, 200.0]), None, 0.2)  # 200 mm off: wrong at every threshold
    b = bop_block(targets, [Best(1, R, t, 0.7, 0.1), shifted], models, 640, 0.5)
    assert b["ar_mssd"] == b["recall_add_s"] == 0.5 and b["per_instance"][1]["te"] == pytest.approx(200.0)
    rows = estimates(targets, [None, shifted])
    assert len(rows) == 1 and rows[0].im_id == 5 and rows[0].score == 1.0  # no confidence: 1
    assert rows[0].time == 0.2


def test_detections_equal_to_the_truth_score_1_and_another_objects_miss(models):
    a, b = instance(1, 0, View(30, 40, 10, 700)), instance(2, 0, View(100, 20, -30, 900))
    c = instance(1, 3, View(200, 30, 0, 800))
    block = detections_block([a, b, c], [guess(a, 0.9), guess(b, 0.2), guess(c, 0.5)], models, 640)
    assert block["ar"] == block["ar_mssd"] == block["ar_mspd"] == 1.0 and block["ar_vsd"] is None
    assert block["recall_add_s"] == block["recall_5deg_5cm"] == 1.0 and block["n_targets"] == 3
    assert all(p[e] == pytest.approx(0.0, abs=1e-4) for p in block["per_instance"] for e in ("mssd", "mspd"))
    assert set(block["per_object"]) == {"1", "2"} and block["per_object"]["1"]["n_targets"] == 2
    # c's estimate names object 2 at c's very pose: no estimate of c's object, so c is missed
    block = detections_block([a, b, c], [guess(a, 0.9), guess(b, 0.2), guess(c, 0.5, obj_id=2)], models, 640)
    assert block["ar_mssd"] == pytest.approx(2 / 3) == block["recall_add_s"] and block["n_estimated"] == 2
    assert block["per_object"]["1"]["ar"] == 0.5 and block["per_object"]["2"]["ar"] == 1.0
    assert block["per_instance"][2]["mssd"] is None and block["per_instance"][2]["n_estimates"] == 0


def test_a_barely_visible_instance_is_no_target(models):
    seen, hidden = instance(1, 0, View(30, 40, 10, 700)), instance(2, 0, View(100, 20, -30, 900), visib=0.05)
    block = detections_block([seen, hidden], [guess(seen, 0.9)], models, 640)  # hidden never estimated
    assert block["n_targets"] == 1 and block["ar"] == 1.0 and set(block["per_object"]) == {"1"}
    assert [p["obj_id"] for p in block["per_instance"]] == [1]
    with pytest.raises(ValueError, match="no targets"):
        detections_block([hidden], [guess(hidden, 0.9)], models, 640)


def test_only_the_n_best_scored_estimates_of_an_image_and_object_count(models):
    a = instance(1, 0, View(30, 40, 10, 700))
    # one target: a wrong estimate scored above a perfect one hides it
    block = detections_block([a], [guess(a, 0.3), guess(a, 0.8, shift_mm=200.0)], models, 640)
    assert block["ar"] == block["recall_add_s"] == block["recall_5deg_5cm"] == 0.0
    assert block["per_instance"][0]["n_estimates"] == 1 and block["per_instance"][0]["te"] == pytest.approx(
        200
    )
    # ... and below it, it changes nothing; an estimate of an object absent from the image costs nothing
    block = detections_block(
        [a], [guess(a, 0.8), guess(a, 0.3, shift_mm=200.0), guess(a, 0.9, 2)], models, 640
    )
    assert block["ar"] == 1.0
    # two instances of object 1 in one frame: the two best-scored count, the third (perfect on b) does not
    b = instance(1, 0, View(200, 30, 0, 800))
    two = [guess(a, 0.9), guess(a, 0.5, shift_mm=200.0), guess(b, 0.1)]
    block = detections_block([a, b], two, models, 640)
    assert block["ar_mssd"] == block["recall_add_s"] == 0.5 and block["per_instance"][1]["n_estimates"] == 2


def test_model_points_are_a_fixed_sample_of_the_vertices():
    sphere = trimesh.creation.icosphere(subdivisions=4)  # 2562 vertices
    a, b = model_points(sphere), model_points(sphere)
    assert len(a) == MAX_POINTS and np.array_equal(a, b)
    assert np.isin(a.view([("", a.dtype)] * 3), sphere.vertices.view([("", a.dtype)] * 3)).all()


# registration (4 in-plane variants a viewpoint) and 4 recognise calls, shipped rgb model: ~6 s on 2 cores
@pytest.mark.slow
def test_evaluate_writes_bop_rows_and_the_block_recomputes(lmo, tmp_path, monkeypatch, capsys):
    if not RGB_MODEL.is_file():
        pytest.skip("the shipped rgb model is not in models/")
    monkeypatch.setenv("POSEDESC_THREADS", "1")
    monkeypatch.delenv("POSEDESC_REJECT_ABOVE", raising=False)
    out, csv = tmp_path / "bop.json", tmp_path / "bop.csv"
    args = ["evaluate", "--dataset", str(lmo), "--modality", "rgb", "--model", str(RGB_MODEL)]
    args += ["--frames", "8,58", "--objects", "1,5", "--methods", "ours", "--inplane-step", "90"]
    assert main([*args, "--json", str(out), "--bop-csv", str(csv)]) == 0
    s = json.loads(out.read_text())
    b, rows = s["bop"], read_bop_csv(csv)
    answered = [p for p in b["per_instance"] if p["answer_obj_id"] is not None]
    assert b["n_targets"] == s["n_samples"] == 4
    assert len(rows) == len(answered) == 4 - s["rejected"]["ours"]["n"]
    assert [(r.im_id, r.obj_id) for r in rows] == [(p["im_id"], p["answer_obj_id"]) for p in answered]
    for r in rows:
        assert np.allclose(r.R @ r.R.T, np.eye(3), atol=1e-6) and r.t[2] > 0 and r.time > 0
    per = b["per_instance"]
    nan = [np.nan if p["mssd"] is None else p["mssd"] for p in per]
    nan_px = [np.nan if p["mspd"] is None else p["mspd"] for p in per]
    again = bop_recall(nan, nan_px, [p["diameter"] for p in per], b["image_width"])
    assert b["ar"] == pytest.approx(again.ar) and b["ar_mssd"] == pytest.approx(again.ar_mssd)
    assert b["image_width"] == 640 and "AR" in capsys.readouterr().out
    # --bop-csv is refused where no BOP rows exist
    assert main([*args, "--protocol", "paper", "--json", str(out), "--bop-csv", str(csv)]) == 2
    assert "--bop-csv needs the service protocol" in capsys.readouterr().err
