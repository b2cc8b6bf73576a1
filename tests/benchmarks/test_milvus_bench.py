"""The milvus section of `posedesc bench` at tiny sizes against the session's real Milvus: both stores hold
the same templates, so Milvus's answers are found by exact search too (recall), and the figures are there,
with the replicas' propagation delay (what tests/promises/test_replicas_share_one_store.py waits for without timing)."""

from __future__ import annotations

import pytest

from benchmarks.stores.milvus import MilvusConfig, run
from benchmarks.table import render

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("services")]  # the session's Milvus: its worker


def test_milvus_section(milvus):
    cfg = MilvusConfig(
        objects=3, large=(2000,), queries=10, recall_queries=20, registrations=1, uri=milvus.uri
    )
    out = run(cfg)
    assert list(out["by_size"]) == ["903", "2000"]
    small, large = out["by_size"]["903"], out["by_size"]["2000"]
    assert small["filled"] == "add_object" and large["filled"] == "bulk"
    for row in (small, large):
        assert row["recall_at_k"] > 0.8  # HNSW over a few thousand templates finds the exact neighbours
        assert row["recognition"]["milvus"]["runs"] == 10 and row["recognition"]["embedded"]["p50_ms"] > 0
        assert row["registration"]["milvus"]["p50_ms"] > 0
    assert "embedded" in small["registration"] and "embedded" not in large["registration"]
    # a replica's store opened after the registrations answers as the first one (it waited until it did)
    start = small["replica_start"]
    assert start["objects"] == 3 and start["runs"] == 3 and 0 < start["p50_s"] <= start["max_s"]
    assert "replica_start" not in large
    # two stores on one Milvus, as two replicas: each saw the other's registration and deletion
    for what in ("registration", "deletion"):
        pr = out["propagation"][what]
        assert pr["runs"] == 1 and pr["seen_p50_ms"] > 0 and pr["call_p50_ms"] > 0
    table = render({"machine": {"cores_usable": 2, "cpu": "x", "load_average_at_start": [0], "load_average_at_end": [0]},
                    "threads": {"onnxruntime_intra_op": 1, "faiss_omp": 1, "opencv": 1}, "seconds": {"total": 1},
                    "sections": {"milvus": out}})  # fmt: skip
    assert "Milvus recall@5" in table and "until the other store shows the change" in table
    assert "a replica's store opened after the registrations" in table
