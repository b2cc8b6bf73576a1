"""posedesc bench: every section at tiny sizes into one JSON with the issue's keys (numbers, not timings)."""

from __future__ import annotations

import json
import math

from posedesc.cli import main
from service.settings import Settings


def positive(x: object) -> bool:
    return isinstance(x, int | float) and math.isfinite(x) and x > 0


def test_bench_quick(tmp_path, posedesc_models, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "--quick", "--models", str(posedesc_models), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "POST /recognize over HTTP" in printed and "LineMOD" in printed and "targets" in printed
    result = json.loads(out.read_text())
    assert positive(result["recognize_vs_linemod_speedup_100"])
    assert positive(result["register_20k_faces_s"])
    # what the sections' services ran with, so two runs can be told apart (POSEDESC_* overrides included)
    assert (
        result["service_settings"]["rerank"] == Settings().rerank
        and "refine_rounds" in result["service_settings"]
    )
    s = result["summary"]
    for key in (
        "onnx_b1_patches_per_s",
        "onnx_b256_patches_per_s",
        "hog_patches_per_s",
        "ours_vs_hog_throughput_ratio",
        "recognize_p50_ms_8",
        "recognize_p50_ms_100",
        "linemod_median_ms_100",
        "knn_flat_ms_10000",
        "knn_ivf_ms_20000",
        "http_p50_ms_c1",
        "http_p99_ms_c2",
        "http_requests_per_s_c2",
        "register_render_s",
        "register_embed_s",
        "register_store_s",
        "train_patches_per_s",
    ):
        assert positive(s.get(key)), (key, s.get(key))
    assert 0.0 <= s["knn_ivf_recall_at_5_20000"] <= 1.0
    assert result["sections"]["register"]["faces"] > 20_000
    assert result["sections"]["http"]["by_concurrency"]["2"]["failed"] == 0
    assert result["threads"]["onnxruntime_intra_op"] == 1 and result["machine"]["cores"] >= 1
    assert result["config"]["quick"] is True
    assert result["sections"]["recognition"]["by_objects"]["100"]["templates"] == 100 * 16
    # roll: the test folder's rgb model has no inplane_step (settings give it 12 per viewpoint); the
    # untrained stand-in has its own and is served
    ro = result["sections"]["roll"]
    assert ro["primary"] == "untrained" and ro["models"]["untrained"]["metadata_inplane_step"] == 30.0
    assert ro["models"]["shipped"]["roll_settings"] == {
        "POSEDESC_INPLANE_STEP": 30.0,
        "POSEDESC_INPLANE_MAX": 180.0,
    }
    for label in ("shipped", "untrained"):
        assert ro["in_process"][label]["roll"]["templates"] == 8 * 16 * 12
        assert ro["in_process"][label]["upright"]["templates"] == 8 * 16
    exact = ro["in_process"]["untrained"]["exact"]  # the served model's templates, searched exactly
    assert exact["templates"] == 8 * 16 * 12 and exact["index"] == "IndexIDMap2"
    assert positive(s["decoded_to_answer_exact_p50_ms_8_q1"])
    assert ro["server"]["templates_per_object"] == {"rgb": 16 * 12, "depth": 16, "rgbd": 16}
    assert ro["server"]["frame_640x480"]["failed"] == 0
    for n in (1, 2, 3):
        for key in ("decoded_to_answer", "decoded_to_answer_upright"):
            assert positive(s[f"{key}_p50_ms_8_q{n}"]) and positive(s[f"{key}_p99_ms_8_q{n}"])
        assert positive(s[f"decoded_to_answer_vs_linemod_speedup_8_q{n}"])
        assert f"decoded_to_answer_p50_ms_100_q{n}" in result["targets"]
    for key in ("roll_http_frame_p50_ms", "roll_register_20k_faces_s", "roll_register_embed_s"):
        assert positive(s[key]), key
    assert s["roll_model_fingerprint"] == ro["models"]["untrained"]["fingerprint"]
    assert "from a decoded patch to the answer" in printed


def test_bench_errors(tmp_path, capsys):
    assert main(["bench", "--quick", "--only", "knn,nope", "--json", str(tmp_path / "b.json")]) == 2
    assert "sections are descriptor" in capsys.readouterr().err
    assert main(["bench", "--objects", "8,x", "--json", str(tmp_path / "b.json")]) == 2
    assert "not a list of numbers" in capsys.readouterr().err
    assert main(["bench", "--query-turns", "1,40", "--json", str(tmp_path / "b.json")]) == 2
    assert "at most 36" in capsys.readouterr().err
    empty = tmp_path / "models"
    empty.mkdir()
    assert main(["bench", "--quick", "--models", str(empty), "--json", str(tmp_path / "b.json")]) == 2
    assert "no rgb model" in capsys.readouterr().err
    assert not (tmp_path / "b.json").exists()
