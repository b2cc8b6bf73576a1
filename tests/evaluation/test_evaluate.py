"""`posedesc evaluate` end to end on a dataset the tests write: the JSON contract, the report, both
baselines on two tiny rendered shapes, synthetic depth scenes, the full protocol, the service protocol's
plumbing (its numbers on real data: test_served.py)."""

import json
from pathlib import Path

import numpy as np
import pytest

from evaluation.baselines.hog import HOG_DIM_PER_CHANNEL, hog_descriptors
from evaluation.config import Config
from evaluation.paper.metric import THRESHOLDS
from evaluation.run import evaluate
from posedesc.cli import main
from tests.evaluation.conftest import N_FRAMES

# the session's tiny BOP dataset and untrained models: made once, on one worker
pytestmark = pytest.mark.xdist_group("tiny-bop")
# every test of the tiny dataset (rendered frames, untrained models made for it) is `slow`: `make test`


def check_table(table: dict) -> None:
    assert set(table) == {f"k{k}" for k in range(1, 23)}
    for k in range(1, 23):
        row = table[f"k{k}"]
        assert set(row) == {str(t) for t in THRESHOLDS}
        values = [row[str(t)] for t in THRESHOLDS]
        assert all(0.0 <= v <= 1.0 for v in values)
        assert values == sorted(values)  # a looser threshold never counts fewer patches
        if k > 1:
            assert all(row[t] >= table[f"k{k - 1}"][t] for t in row)  # nor does a larger k


@pytest.mark.slow
def test_json_contract_and_report(tiny_bop, untrained_models, tmp_path):
    out = tmp_path / "rgb.json"
    args = [
        "evaluate",
        "--dataset",
        str(tiny_bop),
        "--modality",
        "rgb",
        "--model",
        str(untrained_models["rgb"]),
    ]
    args += ["--protocol", "paper", "--unseen", "2", "--frames", "0-3", "--json", str(out)]
    args += ["--report", str(tmp_path / "report")]
    args += ["--model-3d", str(untrained_models["rgb3"])]
    assert main(args) == 0
    summary = json.loads(out.read_text())
    assert summary["modality"] == "rgb" and summary["protocol"] == "paper"
    assert summary["n_samples"] == 8 and summary["test_data"] == "real"
    assert summary["frames"] == [0, 1, 2, 3]
    assert set(summary["methods"]) == {"ours", "hog", "linemod"}
    for table in summary["methods"].values():
        check_table(table)
    assert set(summary["per_object"]) == {"1", "2"}
    for per in summary["per_object"].values():
        for name in ("ours", "hog", "linemod"):
            check_table(per[name])
    assert summary["unseen_objects"]["n_samples"] == 4
    report = tmp_path / "report"
    md = (report / "report.md").read_text()
    assert "| ours | 1 |" in md and "2 (unseen)" in md
    for png in ("accuracy", "distance_vs_angle", "class_separation", "nearest_ours", "descriptors_3d"):
        assert (report / f"{png}.png").stat().st_size > 5000


@pytest.mark.slow
def test_baselines_on_two_tiny_shapes(tiny_bop, untrained_models):
    """Clean renders of two distinct shapes: both baselines find the object and, mostly, the view."""
    cfg = Config(tiny_bop, untrained_models["rgb"], "rgb", protocol="paper", methods=("hog", "linemod"))
    summary = evaluate(cfg).summary()
    assert summary["n_samples"] == 2 * N_FRAMES
    for name in ("hog", "linemod"):
        k1 = summary["methods"][name]["k1"]
        assert k1["180"] >= 0.9, (name, k1)
        assert k1["20"] >= 0.6, (name, k1)


@pytest.mark.slow
def test_depth_on_synthetic_scenes_and_the_full_protocol(tiny_bop, untrained_models, tmp_path):
    """No depth in the dataset: the depth run says it used synthetic scenes. The full protocol's
    templates carry in-plane variants."""
    cfg = Config(
        tiny_bop, untrained_models["depth"], "depth", protocol="full", inplane_step=90.0, frames=[0, 1]
    )
    ev = evaluate(cfg)
    summary = ev.summary()
    assert summary["test_data"] == "synthetic" and summary["notes"]
    assert summary["n_templates"] == 2 * 301 * 4
    assert {v.inplane for v in ev.templates.views} == {-90.0, 0.0, 90.0, 180.0}
    assert ev.samples.depth is not None and (ev.samples.depth > 0).mean() > 0.3
    for table in summary["methods"].values():
        check_table(table)


def test_hog_descriptor_shape():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 255, (3, 64, 64, 3), dtype=np.uint8)
    depth = rng.uniform(380, 420, (3, 64, 64)).astype(np.float32)
    d = hog_descriptors("rgbd", rgb, depth, 400.0, 200.0, fill=True)
    assert d.shape == (3, 4 * HOG_DIM_PER_CHANNEL)
    np.testing.assert_allclose(np.linalg.norm(d.astype(np.float32), axis=1), 1.0, atol=1e-2)


@pytest.mark.slow
def test_bad_input_is_one_line(tiny_bop, untrained_models, tmp_path, capsys):
    base = ["evaluate", "--dataset", str(tiny_bop), "--json", str(tmp_path / "x.json")]
    assert main([*base, "--modality", "depth", "--model", str(untrained_models["rgb"])]) == 2
    assert "is a rgb model" in capsys.readouterr().err
    assert (
        main([*base, "--modality", "rgb", "--model", str(untrained_models["rgb"]), "--methods", "sift"]) == 2
    )
    assert main([*base, "--modality", "rgb", "--model", str(untrained_models["rgb"]), "--frames", "a-b"]) == 2
    assert main([*base, "--modality", "rgb", "--model", str(Path(tmp_path / "none.onnx"))]) == 2


@pytest.mark.slow
def test_heldout_frames_come_from_the_models_metadata(tiny_bop, untrained_models, tmp_path, capsys):
    from evaluation.splits import heldout_frames
    from posedesc.commands.evaluate import parse_ids

    meta = {"heldout_frames": json.dumps({f"{tiny_bop.name}/000002": [3, 1, 2], "other/000002": [9]})}
    assert heldout_frames(meta, tiny_bop, 2) == [1, 2, 3]
    assert heldout_frames(meta, tiny_bop, 5) is None
    assert heldout_frames({}, tiny_bop, 2) is None
    assert parse_ids("8, 1-3,2") == [1, 2, 3, 8]
    args = [
        "evaluate",
        "--dataset",
        str(tiny_bop),
        "--modality",
        "rgb",
        "--model",
        str(untrained_models["rgb"]),
    ]
    assert main([*args, "--frames", "heldout", "--json", str(tmp_path / "x.json")]) == 2
    assert "names no held-out frames" in capsys.readouterr().err
    assert main([*args, "--frames", "test", "--json", str(tmp_path / "x.json")]) == 2
    assert "names no test frames" in capsys.readouterr().err


@pytest.mark.slow
def test_split_frames_come_from_the_models_metadata(tiny_bop):
    from evaluation.splits import split_frames

    splits = {f"{tiny_bop.name}/000002": {"train": [0, 1], "val": [3], "test": [5, 4]}}
    meta = {"split_frames": json.dumps(splits)}
    assert split_frames(meta, tiny_bop, 2, "test") == [4, 5]
    assert split_frames(meta, tiny_bop, 2, "val") == [3]
    assert split_frames(meta, tiny_bop, 5, "test") is None
    assert split_frames({}, tiny_bop, 2, "test") is None


@pytest.mark.slow
def test_service_protocol_plumbing(tiny_bop, untrained_models, tmp_path):
    """The default protocol registers the objects with the service's registration and asks the
    service's `recognise`: both errors, timing, the settings it ran with, every method."""
    out = tmp_path / "service.json"
    args = ["evaluate", "--dataset", str(tiny_bop), "--modality", "rgb"]
    args += ["--model", str(untrained_models["rgb"]), "--frames", "0-3", "--unseen", "2"]
    args += ["--inplane-step", "90", "--inplane-max", "180", "--query-turns", "2", "--json", str(out)]
    args += ["--report", str(tmp_path / "report")]
    assert main(args) == 0
    summary = json.loads(out.read_text())
    assert summary["protocol"] == "service" and summary["n_samples"] == 8
    assert summary["service"]["templates_per_viewpoint"] == 4 and summary["service"]["query_turns"] == 2
    assert summary["n_templates"] == 2 * 301 * 4
    assert summary["timing_ms"]["calls"] == 8 and summary["timing_ms"]["recognise_median"] > 0
    for key in ("methods", "view_direction"):
        assert set(summary[key]) == {"ours", "hog", "linemod"}
        for table in summary[key].values():
            check_table(table)
    for key in ("methods", "view_direction"):  # the open set is ours alone: the baselines reject nothing
        assert set(summary["open_set_off"][key]) == {"ours"}
        check_table(summary["open_set_off"][key]["ours"])
    assert set(summary["rejected"]["ours"]) == {"n", "share", "right_object_first"}
    per_keys = {"ours", "hog", "linemod", "view_direction", "open_set_off", "rejected", "n_samples"}
    for per in (*summary["per_object"].values(), summary["seen_objects"], summary["unseen_objects"]):
        assert set(per) == per_keys
    assert summary["unseen_objects"]["n_samples"] == 4
    assert "| ours | 1 |" in (tmp_path / "report" / "report.md").read_text()


@pytest.mark.slow
def test_the_service_protocol_with_patches(tiny_bop, untrained_models, tmp_path, capsys):
    """`--patches`: each instance sent as the patch a user cuts (`evaluation.queries.patch_query`: no camera,
    its object's window and the distance), ours alone, no BOP block (a patch's pose is in its own camera)."""
    from evaluation import served
    from evaluation.queries import patch_query

    sent = []

    def recorded(q, d, window_mm):
        sent.append(patch_query(q, d, window_mm))
        return sent[-1]

    out = tmp_path / "patches.json"
    args = ["evaluate", "--dataset", str(tiny_bop), "--modality", "rgb", "--model", str(untrained_models["rgb"])]  # fmt: skip
    args += ["--frames", "0-3", "--methods", "ours", "--patches", "--json", str(out)]
    served.patch_query, original = recorded, served.patch_query
    try:
        assert main(args) == 0
    finally:
        served.patch_query = original
    summary = json.loads(out.read_text())
    assert summary["n_samples"] == 8 and summary["timing_ms"]["calls"] == 8 and "bop" not in summary
    assert any(n.startswith("patches:") for n in summary["notes"])
    assert len(sent) == 8 and all(q.camera is None and q.u is None and q.rgb is not None for q in sent)
    assert all(q.window_mm == 200.0 and q.distance_mm and q.distance_mm > 0 for q in sent)
    assert main([*args, "--methods", "ours,hog"]) == 2 and "--patches needs" in capsys.readouterr().err


@pytest.mark.slow
def test_the_true_view_scores_zero(tiny_bop):
    """The service protocol's scoring: an answer giving the annotated view, placed along the ray through
    the object's centre, is the annotated pose (both errors ~0); another object counts 180°."""
    from evaluation.served import score
    from index.data.bop import BopDataset

    instances = list(BopDataset(tiny_bop).instances(2))[:4]
    views = np.array([[[i.view.azimuth, i.view.elevation, i.view.inplane]] * 2 for i in instances])
    obj = np.array([[i.obj_id, 3 - i.obj_id] for i in instances])
    rot, view, same = score(obj, views, instances, {1: "none", 2: "none"})
    assert same[:, 0].all() and not same[:, 1].any()
    np.testing.assert_allclose(rot[:, 0], 0, atol=1e-3)
    np.testing.assert_allclose(view[:, 0], 0, atol=1e-3)
    assert (rot[:, 1] == 180).all() and (view[:, 1] == 180).all()
