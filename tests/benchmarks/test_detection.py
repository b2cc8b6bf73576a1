"""The detect section (`benchmarks.detection`) at a tiny size: one real LM-O colour frame and the Kinect
frame, two then eight objects registered (LM-O meshes, then generated shapes), untrained models: the
test folder's descriptor models and an objectness stand-in that proposes all over the frame. The JSON's
structure and counts, not its speed."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks.detection import DetectConfig, run
from benchmarks.summary import detect_summary
from benchmarks.table import _detect
from index.data.bop import BopDataset
from index.features.objectness import OBJECTNESS_FILE
from service.settings import Settings

STAGES = {"decode", "propose", "verify", "agree", "stand", "merge", "report", "mask", "total"}


@pytest.fixture(scope="module")
def models(posedesc_models: Path, tmp_path_factory) -> Path:
    """The test models and an untrained objectness network beside them, its centre prior one half (the
    trained one starts at 1 %) so that it proposes places in any frame."""
    torch = pytest.importorskip("torch")
    from training.objectness import ObjectnessConfig, ObjectnessNet, export

    folder = tmp_path_factory.mktemp("detect-models")
    for f in posedesc_models.glob("*.onnx"):
        (folder / f.name).symlink_to(f)
    torch.manual_seed(0)
    net = ObjectnessNet(pretrained=False)
    bias = net.head.out.bias
    assert bias is not None
    with torch.no_grad():
        bias[0] = 0.0
    export(net, ObjectnessConfig(), folder / OBJECTNESS_FILE, {"note": "untrained, for tests"})
    return folder


def check_row(r: dict, runs: int) -> None:
    st = r["stages_median_ms"]
    assert set(st) == STAGES and r["runs"] == runs == len(r["proposals"]) == len(r["detections"])
    assert (
        0 < st["verify"] <= st["total"] and st["decode"] + st["propose"] + st["verify"] <= st["total"] + 0.1
    )
    assert 0 < r["p50_ms"] <= r["p90_ms"] <= r["max_ms"]
    assert r["verify_ms_per_proposal"] == pytest.approx(st["verify"] / r["proposals_median"])
    assert all(d <= 10 for d in r["detections"])  # a user's default max_detections


@pytest.mark.slow
def test_a_tiny_detect_run(lmo: Path, models: Path):
    cfg = DetectConfig(counts=(8, 2), frames=1, warmup=0, rgbd_repeats=1)
    out = run(cfg, models, level=0)
    limit = Settings().detect_proposals
    assert list(out["by_objects"]) == ["2", "8"]  # smallest first, the objects added to the same store
    assert len(out["frames"]["colour"]["frames"]) == 1 and out["objectness"] is not None
    two, eight = out["by_objects"]["2"], out["by_objects"]["8"]
    assert eight["templates"]["rgb"] > two["templates"]["rgb"] > 0
    # LM-O's objects and the shapes sized as they are share the model's window (200 mm)
    assert eight["window_classes_mm"] == {"200": 8}
    for n, row in (("2", two), ("8", eight)):
        check_row(row["colour"], 1)
        assert 1 <= row["colour"]["proposals_median"] <= limit, n  # one window class: each verified once
    kinect = (cfg.lmo_depth / "test" / "000002" / "depth" / "000003.png").is_file()
    assert ("rgbd" in two) == kinect and "rgbd" not in eight  # the Kinect frame at the smallest count only
    if kinect:
        check_row(two["rgbd"], 1)
        assert out["models"].keys() == {"rgb", "rgbd"}
    ids = BopDataset(lmo).obj_ids[:8]
    assert out["objects"] == {"lmo": [f"obj_{o:06d}" for o in ids], "generated": 8 - len(ids)}
    reg = out["register"]
    assert reg["objects"] == 8 and sum(b["objects"] for b in reg["by_window_mm"].values()) == 8
    assert reg["by_window_mm"].keys() == {"200"}
    s = detect_summary(out)
    assert s["detect_p50_ms_8"] == eight["colour"]["p50_ms"] and s["detect_proposals_2"] >= 1
    assert {f"detect_{k}_ms_8" for k in STAGES - {"total"}} <= set(s)
    assert ("detect_rgbd_p50_ms_2" in s) == kinect
    text = "\n".join(_detect(out))
    assert "objects found in a whole 640x480 frame" in text and "registrations" in text


@pytest.mark.slow
def test_without_an_objectness_model_colour_rows_are_left_out(lmo: Path, posedesc_models: Path):
    out = run(DetectConfig(counts=(1,), frames=1, warmup=0, rgbd=False), posedesc_models, level=0)
    assert out["objectness"] is None and "colour" not in out["by_objects"]["1"]
    assert any(OBJECTNESS_FILE in note for note in out["notes"])
    assert out["register"]["objects"] == 1


def test_without_lmo_the_section_says_so(tmp_path: Path):
    out = run(DetectConfig(lmo=tmp_path / "lmo"), tmp_path)
    assert out["by_objects"] == {} and out["register"]["objects"] == 0
    assert "no LM-O at" in out["notes"][0] and _detect(out) == [] and detect_summary(out) == {}
