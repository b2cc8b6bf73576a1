"""scripts/train_objectness.py: `measure` reproduces the committed validation figures; bad paths are one line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


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
