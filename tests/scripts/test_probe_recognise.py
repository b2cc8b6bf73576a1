"""scripts/probe_recognise.py on the real frames, small: a store made once and reused, answers compared."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _script():
    spec = importlib.util.spec_from_file_location("probe_recognise", ROOT / "scripts" / "probe_recognise.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_probe_registers_once_and_compares_answers(lmo, tmp_path, capsys):
    probe = _script()
    data, first, second = tmp_path / "store", tmp_path / "a.json", tmp_path / "b.json"
    common = ["--dataset", str(lmo), "--frames", "val", "--limit", "4", "--data-dir", str(data)]
    level = json.dumps({"level": 1})
    assert probe.main([*common, "--distractors", "2", "--settings", level, "--json", str(first)]) == 0
    a = json.loads(first.read_text())
    assert a["n"] == 4 and len(a["best"]) == 4
    assert a["objects"] == 7 + 2  # the dataset's objects and the distractors, in one store
    assert {"patch", "embed", "search", "total"} <= set(a["stages_median_ms"])
    assert 0.0 <= a["k1"]["within_20"] <= a["k1"]["within_40"] <= 100.0
    # the same store again (nothing registered twice), exactly searched this time, compared answer by answer
    flat = json.dumps({"level": 1, "index_kind": "flat"})
    args = [*common, "--settings", flat, "--json", str(second), "--compare", str(first)]
    assert probe.main(args) == 0
    b = json.loads(second.read_text())
    assert b["objects"] == 7 + 2 and b["templates"] == a["templates"]
    assert b["agree_with"]["same_best_answer"] == 100.0  # a small store is exact either way
    assert probe.main([*common, "--settings", "{nope"]) == 2
    assert "--settings is not JSON" in capsys.readouterr().err
