"""posedesc bench: every section at tiny sizes into one JSON with the issue's keys (numbers, not timings)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import pytest

from benchmarks.suite import DEFAULT_SECTIONS, OPT_IN, SECTIONS
from posedesc.cli import main
from posedesc.commands.bench import add_arguments, configure
from service.settings import Settings


def positive(x: object) -> bool:
    return isinstance(x, int | float) and math.isfinite(x) and x > 0


@pytest.mark.slow
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
    for key in (
        "roll_http_frame_p50_ms",
        "roll_http_frame_around_ms",
        "roll_register_20k_faces_s",
        "roll_register_embed_s",
    ):
        assert positive(s[key]), key
    assert s["roll_model_fingerprint"] == ro["models"]["untrained"]["fingerprint"]
    # every key of the pipeline's timings_ms, median and p90, of the primary model's in-plane set-up
    for n in (1, 2, 3):
        med, p90 = ro[f"stages_ms_8_q{n}"], ro[f"stages_p90_ms_8_q{n}"]
        assert {"cut", "embed", "search", "patch", "total"} <= set(med) and set(med) == set(p90)
        assert all(positive(v) for v in med.values()) and all(p90[k] >= med[k] for k in med)
        assert med == ro["in_process"]["untrained"]["roll"]["by_turns"][str(n)]["stages_median_ms"]
    assert "per stage (timings_ms)" in printed
    assert "from a decoded patch to the answer" in printed
    # guards, quick: the small hostile uploads over HTTP, the declaring meshes, 20 fuzz cases, a busy port
    g = result["sections"]["guards"]
    assert g["uploads"] and all(u["status"] == u["expected"] for u in g["uploads"].values()), g["uploads"]
    assert all(u["runs"] == 1 and positive(u["median_ms"]) for u in g["uploads"].values())
    assert all(d["refused"] for d in g["declaring"].values()) and len(g["declaring"]) == 5
    assert g["fuzz"]["cases"] == 20 and g["fuzz"]["other_error"] == 0
    assert g["fuzz"]["loaded"] + g["fuzz"]["refused"] == 20
    assert g["busy_port"]["exit_codes"] == [2]
    for key in (
        "guards_upload_max_ms",
        "guards_declaring_max_ms",
        "guards_fuzz_max_ms",
        "guards_busy_port_s",
    ):
        assert positive(s[key]), key
    assert "hostile uploads refused by the service" in printed and "posedesc serve on a busy port" in printed


def options(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return parser.parse_args(["--json", "b.json", *argv])


def test_the_default_run_leaves_out_the_opt_in_parts():
    """What takes the default past ten minutes on two cores is opt-in (--all, or named)."""
    cfg = configure(options())
    assert cfg.sections == DEFAULT_SECTIONS and "guards" in cfg.sections
    assert "milvus" not in cfg.sections and "memory" not in cfg.sections
    assert "fit" not in cfg.sections and cfg.fit.frames is None  # the rgb model's val frames when asked
    assert max(cfg.recognition.counts) == 100 and cfg.roll.models == ("shipped",)
    assert "detect" in cfg.sections and cfg.detect.counts == (8,)
    every = configure(options("--all"))
    assert every.sections == SECTIONS and "milvus" in every.sections and "fit" in every.sections
    assert 1000 in every.recognition.counts and every.roll.models == ("shipped", "untrained")
    assert every.detect.counts == (8, 100)
    assert every.guards == cfg.guards and every.knn == cfg.knn  # the rest at the default's sizes
    # each opt-in part can be asked for alone, as OPT_IN says
    assert configure(options("--only", "milvus")).sections == ("milvus",)
    fit = configure(options("--only", "fit", "--fit-frames", "224,243"))
    assert fit.sections == ("fit",) and fit.fit.frames == (224, 243)
    assert configure(options("--objects", "8,100,1000")).recognition.counts == (8, 100, 1000)
    assert configure(options("--roll-models", "shipped,untrained")).roll.models == ("shipped", "untrained")
    assert configure(options("--detect-objects", "8,100")).detect.counts == (8, 100)
    memory = configure(options("--only", "memory", "--memory-objects", "100,300,1000"))
    assert memory.sections == ("memory",) and memory.memory.counts == (100, 300, 1000)
    assert len(OPT_IN) == 6
    assert configure(options("--profile", "p")).roll.profile == Path("p") and cfg.roll.profile is None
    quick = configure(options("--quick"))
    assert quick.guards.small_only and quick.guards.fuzz_cases < cfg.guards.fuzz_cases


def test_bench_errors(tmp_path, capsys):
    assert main(["bench", "--quick", "--only", "knn,nope", "--json", str(tmp_path / "b.json")]) == 2
    assert "sections are descriptor" in capsys.readouterr().err
    assert main(["bench", "--objects", "8,x", "--json", str(tmp_path / "b.json")]) == 2
    assert "not a list of numbers" in capsys.readouterr().err
    assert main(["bench", "--query-turns", "1,40", "--json", str(tmp_path / "b.json")]) == 2
    assert "at most 36" in capsys.readouterr().err
    assert main(["bench", "--only", "knn", "--profile", "p", "--json", str(tmp_path / "b.json")]) == 2
    assert "add roll to --only" in capsys.readouterr().err
    empty = tmp_path / "models"
    empty.mkdir()
    assert main(["bench", "--quick", "--models", str(empty), "--json", str(tmp_path / "b.json")]) == 2
    assert "no rgb model" in capsys.readouterr().err
    assert not (tmp_path / "b.json").exists()
