"""scripts/loo_table.py: each run's left-out object beside the others, and the runs pooled."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest


def _evaluation(path: Path, unseen: tuple[int, float, float], seen: tuple[int, float, float]) -> str:
    def group(n: int, within: float, recognised: float) -> dict:
        return {"n_samples": n, "ours": {"k1": {"20": within, "180": recognised}}}

    path.write_text(
        json.dumps(
            {
                "model": "m.onnx",
                "frames": [1, 2],
                "unseen_objects": group(*unseen),
                "seen_objects": group(*seen),
            }
        )
    )
    return str(path)


def test_runs_and_their_pool(tmp_path, monkeypatch, capsys, script):
    a = _evaluation(tmp_path / "a.json", (20, 0.5, 0.8), (100, 0.7, 0.9))
    b = _evaluation(tmp_path / "b.json", (30, 0.6, 0.6), (90, 0.6, 0.8))
    out = tmp_path / "table.json"
    monkeypatch.setattr(sys, "argv", ["loo_table.py", f"1={a}", f"6={b}", "--json", str(out)])
    script("loo_table").main()
    table = json.loads(out.read_text())
    assert [t["left_out"] for t in table] == [1, 6, "pooled"]
    pool = table[-1]
    assert pool["unseen"]["n"] == 50 and pool["seen"]["n"] == 190
    assert pool["unseen"]["within_20"]["value"] == pytest.approx((10 + 18) / 50)
    assert pool["unseen"]["recognised"]["value"] == pytest.approx((16 + 18) / 50)
    assert pool["seen"]["within_20"]["value"] == pytest.approx((70 + 54) / 190)
    lo, hi = pool["unseen"]["within_20"]["ci95"]
    assert (
        lo < 28 / 50 < hi
        and hi - lo < table[0]["unseen"]["within_20"]["ci95"][1] - table[0]["unseen"]["within_20"]["ci95"][0]
    )
    assert "| pooled | 50 |" in capsys.readouterr().out
