"""The fit section (`benchmarks.fit`) at a tiny size: one real LM-O validation frame and the Kinect frame, two
LM-O objects at level-0 templates, untrained models. The JSON's shape, and that the calls with the fit on
report its time while those with it off do not; not its speed."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks.fit import FitConfig, run, summary
from benchmarks.summary import targets_met
from benchmarks.table import render

FRAME = 224  # the first of the shipped rgb model's val frames; ape (1) and can (5) are in it
SIDE_KEYS = {"runs", "refused", "call_p50_ms", "call_p90_ms", "wall_p50_ms", "stages_median_ms", "fit_runs",
             "fit_p50_ms", "fit_p90_ms", "fit_max_ms", "fit_moved", "right_object"}  # fmt: skip


@pytest.mark.slow
def test_a_tiny_fit_run(lmo: Path, posedesc_models: Path):
    cfg = FitConfig(frames=(FRAME,), objects=2, warmup=0, kinect_repeats=1)
    out = run(cfg, posedesc_models, level=0)
    assert out["objects"] == ["obj_000001", "obj_000005"] and out["frames"]["frames"] == [FRAME]
    kinect = (cfg.lmo_depth / "test" / "000002" / "depth" / "000003.png").is_file()
    assert set(out["rows"]) == {"colour", "rendered_depth"} | ({"kinect_depth"} if kinect else set())
    for name, row in out["rows"].items():
        assert row["modality"] == ("rgb" if name == "colour" else "rgbd"), name
        on, off = row["on"], row["off"]
        assert set(on) == set(off) == SIDE_KEYS
        assert on["runs"] + on["refused"] == off["runs"] + off["refused"] == row["calls"] >= 1
        # the fit's own time where it is on, none where it is off: per call, one answer fitted
        assert on["fit_runs"] == on["runs"] and "fit" in on["stages_median_ms"]
        assert 0 < on["fit_p50_ms"] <= on["fit_p90_ms"] <= on["fit_max_ms"]
        # each call's fit is part of that call, so each percentile of the fits is at most the calls' (the
        # slowest fit may pass the calls' 90th percentile: its call may be the slowest)
        assert on["fit_p90_ms"] <= on["call_p90_ms"]
        assert off["fit_runs"] == 0 and off["fit_p50_ms"] is None and "fit" not in off["stages_median_ms"]
        assert off["fit_moved"] == 0 and 0 <= on["fit_moved"] <= on["fit_runs"]
        assert row["call_p50_ratio_on_off"] == pytest.approx(on["call_p50_ms"] / off["call_p50_ms"])
    if kinect:  # can's instance, once (the ape's is 20 % visible there, under min_visib)
        assert out["rows"]["kinect_depth"]["calls"] == 1 and "Kinect" in out["rows"]["kinect_depth"]["data"]
    assert out["rows"]["rendered_depth"]["data"].startswith("rendered")
    made = out["models_made"]
    assert set(made["by_object"]) == set(out["objects"])
    for m in made["by_object"].values():
        assert m["colour_s"] > 0 and m["depth_s"] > 0 and m["colour_bytes"] > 0 and m["depth_bytes"] > 0
    s = summary(out)
    assert s["fit_colour_p50_ms"] == out["rows"]["colour"]["on"]["fit_p50_ms"]
    assert s["fit_colour_call_p50_ms_off"] == out["rows"]["colour"]["off"]["call_p50_ms"]
    depth_row = "kinect_depth" if kinect else "rendered_depth"
    assert s["fit_depth_p50_ms"] == out["rows"][depth_row]["on"]["fit_p50_ms"]
    targets = targets_met(s)
    assert targets["fit_colour_p50_ms"]["value"] == s["fit_colour_p50_ms"]
    assert targets["fit_depth_p50_ms"]["value"] == s["fit_depth_p50_ms"]
    text = render({"machine": {"cores_usable": 2, "cpu": "x", "load_average_at_start": [0], "load_average_at_end": [0]},
                   "threads": {"onnxruntime_intra_op": 1, "faiss_omp": 1, "opencv": 1}, "seconds": {"total": 1},
                   "sections": {"fit": out}})  # fmt: skip
    assert "the pose fit" in text and "colour" in text


def test_without_lmo_the_section_says_so(tmp_path: Path):
    out = run(FitConfig(lmo=tmp_path / "lmo"), tmp_path)
    assert out["rows"] == {} and "no LM-O at" in out["notes"][0] and summary(out) == {}
