"""scripts/probe_appearance.py: with nothing trained on the ape, the frames that look like its renders are
where it stands; a missing model is a one-line error."""

from __future__ import annotations

import json

import pytest


def test_the_ape_is_found_where_the_frame_looks_like_its_renders(tmp_path, lmo, script) -> None:
    out = tmp_path / "probe.json"
    args = ["--data", str(lmo), "--split", "val", "--objects", "1", "--max-frames", "3", "--json", str(out)]
    assert script("probe_appearance").main(args) == 0
    result = json.loads(out.read_text())
    assert result["instances"] == 3 and result["objects"] == [1]
    # on every validation frame it stands in, the ape is among its 10 best places within an eighth window
    assert result["recall_in_own_top10"]["w/8, any scale"]["1"] == 1.0


def test_a_missing_model_is_a_one_line_error(tmp_path, capsys, script) -> None:
    with pytest.raises(SystemExit) as e:
        script("probe_appearance").main(["--objectness", str(tmp_path / "none.onnx")])
    assert e.value.code == 2
    assert "none.onnx does not exist" in capsys.readouterr().err.strip().splitlines()[-1]
