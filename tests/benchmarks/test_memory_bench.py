"""The memory section of `posedesc bench` at tiny sizes (level-1 templates, 2 and 4 objects) with the shipped
models: the accounting finds what the store holds (the RGB-D model sharing the rgb model's index, the local
features mapped from files, not in the heap), the probe process answered a query per model, and the table
shows the slope."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks.stores.memory import MemoryConfig, run
from benchmarks.table import render

pytestmark = pytest.mark.slow

MODELS = Path(__file__).resolve().parents[2] / "models"


def test_memory_section():
    out = run(MemoryConfig(counts=(2, 4), level=1), MODELS)
    assert list(out["by_count"]) == ["2", "4"]
    for n, row in out["by_count"].items():
        acc = row["accounting"]
        assert acc["objects"] == int(n)
        rgb, rgbd = acc["models"]["rgb"], acc["models"]["rgbd"]
        assert rgbd["descriptors"]["shared_with"] == "rgb" and rgbd["descriptors"]["ram_bytes"] == 0
        viewpoints, width = rgb["local"]["shape"]
        assert rgb["local"]["dtype"] == "float16" and rgb["local"]["ram_anonymous_bytes"] == 0
        assert rgb["local"]["ram_mapped_bytes"] == viewpoints * width * 2
        assert rgbd["disk"]["sqlite_local_bytes"] < 100 * viewpoints  # pointers to rgb's rows, no copy
        assert (
            set(row["top1"]) == {"rgb", "depth", "rgbd"} and row["queried"]["VmRSS"] > row["models"]["VmRSS"]
        )
    assert set(out["slope_mb_per_object"]) >= {"queried_VmRSS", "queried_RssAnon"}
    table = render({"machine": {"cores_usable": 2, "cpu": "x", "load_average_at_start": [0], "load_average_at_end": [0]},
                    "threads": {"onnxruntime_intra_op": 1, "faiss_omp": 1, "opencv": 1}, "seconds": {"total": 1},
                    "sections": {"memory": out}})  # fmt: skip
    assert "MB resident per object" in table
