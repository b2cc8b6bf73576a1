"""scripts/probe_patch_windows.py: a mesh's `render --patches` queries sent as written, every answer counted."""

from __future__ import annotations

import json

import pytest

pytestmark = pytest.mark.slow


def test_the_queries_of_a_small_mesh_are_answered_through_its_window(tmp_path, script) -> None:
    out = tmp_path / "probe.json"
    assert script("probe_patch_windows").main(["--sizes", "35", "--level", "1", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    assert {r["window_mm"] for r in result["rows"]} == {50.0}  # a 35 mm object's window
    assert result["all"]["n"] == 20 and set(result["by_kind"]) == {
        "patch-rgb",
        "patch-depth",
        "patch-rgbd",
        "frame-rgb",
        "frame-rgbd",
    }
    assert result["all"]["confidently wrong"] == 0 and result["all"]["refused"] == 0
    assert result["by_kind"]["patch-depth"]["right"] >= 3  # of 4 views: its window's objects alone
