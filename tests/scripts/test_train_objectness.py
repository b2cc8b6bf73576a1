"""scripts/train_objectness.py: `measure` reproduces the committed validation figures; bad paths are one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


# the objectness network over 20 real frames: ~4.5 s
@pytest.mark.slow
def test_measure_reproduces_the_committed_validation_recall(tmp_path, lmo, script) -> None:
    pytest.importorskip("torch")  # the frames are read by training/objectness/
    out = tmp_path / "val.json"
    assert (
        script("train_objectness").main(["measure", "--split", "val", "--repeats", "1", "--json", str(out)])
        == 0
    )
    now, committed = (
        json.loads(out.read_text()),
        json.loads((ROOT / "docs/results/objectness-val.json").read_text()),
    )
    assert now["instances"] == committed["instances"] == 115
    assert now["recall_by_window"] == committed["recall_by_window"]
    assert now["recall_by_extent_and_true_diameter"] == committed["recall_by_extent_and_true_diameter"]
    assert now["per_object_w8_12"] == committed["per_object_w8_12"] and now["held_out"] == []
    assert now["propose_ms_640x480_median"] > 0


def test_a_missing_model_is_a_one_line_error(tmp_path, capsys, script) -> None:
    with pytest.raises(SystemExit) as e:
        script("train_objectness").main(["measure", "--model", str(tmp_path / "none.onnx")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "none.onnx does not exist" in err[-1]


@pytest.mark.slow
def test_a_catalogue_run_trains_on_random_urdfs_with_every_real_object_held(tmp_path, lmo, script) -> None:
    """The issue-51 recipe (docs/experiments.md) end to end on a tiny budget: pybullet's meshes rendered,
    photo-coloured, pasted with decoys over the train frames whose annotated objects are never learned;
    a checkpoint chosen by the recall read from the extent."""
    pytest.importorskip("torch")
    pytest.importorskip("pybullet_data")
    run = tmp_path / "run"
    args = [
        "train",
        "--data",
        str(lmo),
        "--out",
        str(run),
        "--cache",
        str(tmp_path / "cache"),
        "--minutes",
        "0.2",
    ]
    args += ["--threads", "1", "--objects", "catalogue", "--shapes", "6", "--shape-views", "1"]
    args += ["--real-objects", "held", "--background", "ignore", "--negative-paste", "0.25", "--paste", "1,6"]
    args += ["--photo-share", "0.6", "--harmonise", "0.5", "--select-by", "extent", "--val-every", "5"]
    args += ["--batch", "2"]
    assert script("train_objectness").main(args) == 0
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert log and log[0]["val"]["n"] == 115  # every validation object measured: none was trained on
    assert (run / "best.pt").is_file() and list((tmp_path / "cache").glob("catalogue-6x1-*-photo0.6.npz"))
