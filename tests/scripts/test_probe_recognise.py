"""scripts/probe_recognise.py on the real frames, small: a store made once and reused, answers compared."""

from __future__ import annotations

import json

import numpy as np
import pytest


@pytest.mark.slow
def test_probe_registers_once_and_compares_answers(lmo, tmp_path, capsys, script):
    probe = script("probe_recognise")
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
    # every frame again at a camera roll: the same instances, answered one query per roll, compared query
    # by query with the run at roll 0 alone (its queries are the rolled run's first roll)
    rolled = tmp_path / "c.json"
    assert (
        probe.main(
            [*common, "--settings", level, "--rolls", "0,180", "--json", str(rolled), "--compare", str(first)]
        )
        == 0
    )
    c = json.loads(rolled.read_text())
    assert c["rolls"] == [0.0, 180.0] and c["n"] + c["rolls_dropped"] == 8 and len(c["queries"]) == c["n"]
    assert c["by_roll"]["0"]["n"] == 4 and c["paired"]["n"] == 4  # roll 0: the frames as they are
    assert c["paired"]["within_20"]["difference"] == 0.0  # the same store, the same queries, the same answers
    assert probe.main([*common, "--rolls", "0,400"]) == 2
    assert "--rolls" in capsys.readouterr().err
    # more answers than the service's default cap: whether any of them is within 20 deg, per query
    many = tmp_path / "d.json"
    assert probe.main([*common, "--settings", level, "--k", "150", "--json", str(many)]) == 0
    d = json.loads(many.read_text())
    assert d["among_k"]["k"] == 150 and len(d["reach"]) == d["n"] == 4
    assert d["k1"] == a["k1"]  # the same first answers
    assert d["among_k"]["within_20"] >= d["k1"]["within_20"]
    assert all(
        r[0] <= r[1] for r in d["reach"]
    )  # a 3-D pose within 20 deg has its viewing direction within 20
    assert probe.main([*common, "--k", "0"]) == 2
    assert "--k must be >= 1" in capsys.readouterr().err


def test_paired_differences_resample_instances_not_queries(script):
    paired = script("probe_recognise").paired
    # 20 instances at 4 rolls; B is wrong (180°) on every roll of instances 0-5 where A is right (10°)
    ours = [[f, 1, r, 10.0, 10.0, 1] for f in range(20) for r in (0, 90, 180, 270)]
    theirs = [[f, 1, r, *((180.0, 180.0, 0) if f < 6 else (10.0, 10.0, 1))] for f, _, r, *_ in ours]
    out = paired(ours, theirs, "B")
    assert out["n"] == 80 and out["instances"] == 20
    d = out["within_20"]
    assert d["difference"] == 30.0 and d["better"] == 24 and d["worse"] == 0
    lo, hi = d["interval_95"]
    # resampling 20 instances (6 of them different), not 80 queries: about ±20 points (queries: ±10)
    assert 0 < lo < 30.0 < hi and hi - lo > 30
    assert out["right_object"]["difference"] == 30.0 and out["within_5"]["difference"] == 0.0
    assert paired(ours, [[99, 1, 0, 1.0, 1.0, 1]], "none") == {"against": "none", "n": 0}


class _AllBackground:
    """An embedder whose mask says nothing is the object."""

    size = 64

    def mask(self, inputs, batch=256):
        return np.zeros((len(inputs), 64, 64), bool)


def test_true_mask_replaces_the_first_cut_s_mask_in_whole_or_in_part(script):
    TrueMask = script("probe_recognise").TrueMask
    true = np.zeros((64, 64), bool)
    true[16:48, 16:48] = True
    one = np.zeros((1, 3, 64, 64), np.float32)
    full, band, inner = (TrueMask(_AllBackground(), how) for how in ("full", "band", "inner"))
    for m in (full, band, inner):
        m.true = true
    assert np.array_equal(full.mask(one)[0], true)
    ring = band.mask(one)[0]  # the true mask within 2 px of its outline, the model's (nothing) elsewhere
    assert ring[16, 16] and ring[17, 30] and not ring[19, 30] and not ring[32, 32] and not ring[14, 30]
    core = inner.mask(one)[0]  # the true mask away from the outline
    assert core[32, 32] and not core[17, 30] and not core[5, 5]
    assert not full.mask(one).any()  # once a query: the next cut gets the model's mask
    assert full.size == 64  # the rest is the embedder's
    assert not band.mask(np.zeros((3, 3, 64, 64), np.float32)).any()  # the re-ranking's cuts: the model's


def test_a_name_that_is_no_setting_is_refused(tmp_path, capsys, script):
    """The settings ignore names they do not have: a stage's constant, once a setting, would be tried silently."""
    probe = script("probe_recognise")
    assert probe.main(["--dataset", str(tmp_path), "--settings", '{"roll_refine": 20}']) == 2
    assert "no such setting: roll_refine" in capsys.readouterr().err
