"""scripts/pool_results.py: the pooled YCB-V results are what the committed per-video runs give; shares are
weighted by queries, counts summed; anything but a service result is a one-line error."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"


def test_the_pooled_ycbv_results_are_the_committed_ones(tmp_path, script) -> None:
    runs = [RESULTS / f"ycbv-service-depth-{s}-lovo.json" for s in range(3)]
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


def test_the_pooled_ycbv_detections_are_made_again_from_the_counts(tmp_path, script) -> None:
    runs = [RESULTS / f"ycbv-detect-rgbd-{s}-lovo.json" for s in range(3)]
    out = tmp_path / "pooled.json"
    assert script("pool_results").main([*map(str, runs), "--json", str(out)]) == 0
    now = json.loads(out.read_text())
    committed = json.loads((RESULTS / "ycbv-detect-rgbd.json").read_text())
    assert now["posedesc"] == committed["posedesc"] and now["bop"] == committed["bop"]
    parts = [json.loads(r.read_text())["posedesc"]["all"] for r in runs]
    tp, targets = sum(p["true_positives"] for p in parts), sum(p["targets"] for p in parts)
    found = sum(p["true_positives"] + p["false_positives"] for p in parts)
    assert now["posedesc"]["all"]["recall"] == pytest.approx(tp / targets)
    assert now["posedesc"]["all"]["precision"] == pytest.approx(tp / found)  # not a mean of the precisions
    assert now["frames"] == 60 and "ap50" not in now["posedesc"]["all"]
    # the false detections with none of the objects registered (--false-alarms): per frame over all frames
    alarms = [json.loads(r.read_text())["false_alarms"] for r in runs]
    assert now["false_alarms"] == committed["false_alarms"] and now["false_alarms"]["frames"] == 60
    per_frame = sum(a["posedesc"]["detections_per_frame"] * a["frames"] for a in alarms) / 60
    assert now["false_alarms"]["posedesc"]["detections_per_frame"] == pytest.approx(per_frame)


@pytest.mark.parametrize(
    "files, says",
    [
        (["bench-detect.json"], "not a service- or detect-protocol result"),
        (["ycbv-detect-rgbd-0.json", "ycbv-service-depth-0-sym.json"], "of one protocol"),
    ],
)
def test_what_cannot_be_pooled_is_a_one_line_error(tmp_path, capsys, script, files, says) -> None:
    with pytest.raises(SystemExit) as e:
        script("pool_results").main([*(str(RESULTS / f) for f in files), "--json", str(tmp_path / "x.json")])
    assert e.value.code == 2
    assert says in capsys.readouterr().err.strip().splitlines()[-1]
