"""scripts/pool_results.py: the pooled YCB-V results are what the committed per-video runs give; shares are
weighted by queries, counts summed; anything but a service result is a one-line error."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"


def test_the_pooled_ycbv_results_are_the_committed_ones(tmp_path, script) -> None:
    runs = [RESULTS / f"ycbv-service-depth-{s}-sym.json" for s in range(3)]
    out = tmp_path / "pooled.json"
    assert script("pool_results").main([*map(str, runs), "--json", str(out)]) == 0
    now, committed = (
        json.loads(out.read_text()),
        json.loads((RESULTS / "ycbv-service-depth.json").read_text()),
    )
    assert now["methods"] == committed["methods"] and now["bop"] == committed["bop"]
    parts = [json.loads(r.read_text()) for r in runs]
    n = [p["n_samples"] for p in parts]
    right = sum(p["methods"]["ours"]["k1"]["180"] * k for p, k in zip(parts, n, strict=True)) / sum(n)
    assert now["n_samples"] == sum(n) and now["methods"]["ours"]["k1"]["180"] == pytest.approx(right)
    assert now["rejected"]["ours"]["n"] == sum(p["rejected"]["ours"]["n"] for p in parts)  # a count


def test_a_result_of_another_protocol_is_a_one_line_error(tmp_path, capsys, script) -> None:
    with pytest.raises(SystemExit) as e:
        script("pool_results").main([str(RESULTS / "detect-test.json"), "--json", str(tmp_path / "x.json")])
    assert e.value.code == 2
    assert "not a service-protocol result" in capsys.readouterr().err.strip().splitlines()[-1]
