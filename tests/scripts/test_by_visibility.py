"""scripts/by_visibility.py: a probe's answers by the share of the object its frame shows."""

from __future__ import annotations

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_bands_count_each_query_once(script):
    by_visibility = script("by_visibility")
    visible = {(1, 5): 0.6, (1, 6): 0.9, (2, 5): 0.99}
    # frame, object, roll, 3-D error, view error, right object
    queries = [
        [1, 5, 0.0, 10.0, 10.0, 1],
        [1, 5, 72.0, 30.0, 10.0, 0],
        [1, 6, 0.0, 50.0, 50.0, 1],
        [2, 5, 0.0, 5.0, 3.0, 1],
    ]
    bands = by_visibility.by_band(queries, visible)
    assert [b["visible"] for b in bands] == [[0.5, 0.8], [0.8, 0.95], [0.95, 1.0]]
    assert [b["n"] for b in bands] == [2, 1, 1]
    assert bands[0] == {
        "visible": [0.5, 0.8],
        "n": 2,
        "within_20": 50.0,
        "view_within_20": 100.0,
        "right_object": 50.0,
    }
    assert bands[1]["within_20"] == 0.0 and bands[2]["within_20"] == 100.0
    # with the probe's `reach` (any of a query's k answers within 20 deg: 3-D, view)
    reached = by_visibility.by_band(queries, visible, [[1, 1], [0, 1], [1, 1], [1, 1]])
    assert (reached[0]["within_20_among_k"], reached[0]["view_within_20_among_k"]) == (50.0, 100.0)
    assert reached[1]["within_20_among_k"] == 100.0 and "within_20_among_k" not in bands[1]


def test_a_committed_probe_on_the_real_scene(lmo, tmp_path, capsys, script):
    """The rolled validation yardstick's 560 queries all fall in a band, each instance at least half visible
    (the evaluation's selection), and the share within 20 deg grows with what the frame shows."""
    probe = ROOT / "docs" / "results" / "probe-val-rolls5-rerank400.json"
    out = tmp_path / "bands.json"
    assert script("by_visibility").main(["--dataset", str(lmo), str(probe), "--json", str(out)]) == 0
    bands = json.loads(out.read_text())["by_visibility"][probe.name]
    assert sum(b["n"] for b in bands) == len(json.loads(probe.read_text())["queries"]) == 560
    assert bands[0]["visible"][0] >= 0.5
    within = [b["within_20"] for b in bands]
    assert within == sorted(within) and within[-1] - within[0] > 20
    assert "within 20" in capsys.readouterr().out


def test_a_file_without_queries_is_refused_in_one_line(lmo, tmp_path, capsys, script):
    bad = tmp_path / "test-rgb.json"
    bad.write_text(json.dumps({"k1": {}}))
    assert script("by_visibility").main(["--dataset", str(lmo), str(bad)]) == 2
    err = capsys.readouterr().err
    assert "has no queries" in err and err.count("\n") == 1
