"""Every protocol of `posedesc evaluate` with every modality it supports, on two real LM-O frames with the
SHIPPED models (`models/`): the documented commands must run with what we ship (skipped without
../shared/data/lmo). Small on purpose: two objects, frames 8 and 58 (four instances), the service with
four in-plane variants a viewpoint, the full protocol with four; the paper's and the full protocol's
templates are rendered once for all three modalities. Not a benchmark: it checks that each run answers
and that its tables are well formed; test_served.py checks the service's figures."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from evaluation.config import Config
from evaluation.paper.protocol import evaluate_templates, protocol_views
from evaluation.paper.templates import render_template_set
from evaluation.run import evaluate
from index.data.bop import BopDataset
from index.features.embed import Embedder
from posedesc.cli import main
from tests.evaluation.test_evaluate import check_table

# every protocol with the shipped models: about a minute and a half on 2 cores; the module's fixtures made
# once, on one worker (on two, each made the 25 s service runs and the paper runs)
pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("shipped-models")]

ROOT = Path(__file__).resolve().parents[2]
MODELS = {m: ROOT / "models" / f"posedesc-{m}.onnx" for m in ("rgb", "depth", "rgbd")}
FRAMES, OBJECTS = (8, 58), (1, 5)
INPLANE_STEP = 90.0  # four in-plane variants a viewpoint: the service's and the full protocol's
MODALITIES = ("rgb", "depth", "rgbd")


def config(lmo: Path, modality: str, protocol: str, **kw) -> Config:
    return Config(
        dataset=lmo,
        model=MODELS[modality],
        modality=modality,
        protocol=protocol,
        methods=("ours",),
        frames=FRAMES,
        objects=OBJECTS,
        inplane_step=INPLANE_STEP,
        **kw,
    )


@pytest.fixture(scope="module")
def shipped(lmo) -> dict[str, Embedder]:
    if not all(p.is_file() for p in MODELS.values()):
        pytest.skip("the shipped models are not in models/")
    return {m: Embedder(p, threads=1) for m, p in MODELS.items()}


@pytest.fixture(scope="module")
def paper_runs(lmo, shipped) -> dict[tuple[str, str], dict]:
    """paper and full, each modality, on one render per protocol (rgb and depth kept: every modality)."""
    dataset = BopDataset(lmo)
    meshes = {o: dataset.mesh(o) for o in OBJECTS}
    out = {}
    for protocol in ("paper", "full"):
        cfg = config(lmo, "rgbd", protocol)
        views = protocol_views(cfg, {o: dataset.symmetry(o) for o in OBJECTS})
        templates = render_template_set(meshes, views, "rgbd", shipped["rgb"].info.window_mm)
        for m in MODALITIES:
            ev = evaluate_templates(config(lmo, m, protocol), shipped[m], templates)
            out[protocol, m] = ev.summary()
    return out


@pytest.fixture(scope="module")
def service_runs(lmo, shipped) -> dict[str, dict]:
    """The service protocol, each modality (the service's own registration and `recognise`), and depth
    again with every answer rejected (POSEDESC_REJECT_ABOVE=0: any distance is above it)."""
    out = {}
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("POSEDESC_THREADS", "1")
        mp.delenv("POSEDESC_REJECT_ABOVE", raising=False)
        for m in MODALITIES:
            out[m] = evaluate(config(lmo, m, "service")).summary()
        mp.setenv("POSEDESC_REJECT_ABOVE", "-1000")  # below any statistic (the lead's can be negative)
        out["depth rejecting all"] = evaluate(config(lmo, "depth", "service")).summary()
    return out


def check_run(s: dict, modality: str, protocol: str) -> None:
    assert s["modality"] == modality and s["protocol"] == protocol
    assert s["frames"] == list(FRAMES) and s["objects"] == list(OBJECTS) and s["n_samples"] == 4
    check_table(s["methods"]["ours"])
    assert s["methods"]["ours"]["k22"]["180"] > 0  # the shipped models find some of them (not a benchmark)


@pytest.mark.parametrize("modality", MODALITIES)
@pytest.mark.parametrize("protocol", ["paper", "full"])
def test_the_paper_protocols_run_with_the_shipped_models(paper_runs, protocol, modality):
    s = paper_runs[protocol, modality]
    check_run(s, modality, protocol)
    per_viewpoint = 1 if protocol == "paper" else 360 / INPLANE_STEP
    assert s["n_templates"] == 2 * 301 * per_viewpoint  # neither object is symmetric
    assert "open_set_off" not in s  # ranked templates: no open set


@pytest.mark.parametrize("modality", MODALITIES)
def test_the_service_protocol_runs_with_the_shipped_models(service_runs, modality):
    s = service_runs[modality]
    check_run(s, modality, "service")
    variants = s["service"]["templates_per_viewpoint"]
    # every shipped model is trained with roll (its metadata's inplane_step): the whole turn, every 90 deg
    assert variants == 4 and s["n_templates"] == 2 * 301 * variants
    check_table(s["view_direction"]["ours"])
    off, on = s["open_set_off"]["methods"]["ours"], s["methods"]["ours"]
    check_table(off)
    rejected = s["rejected"]["ours"]
    assert 0 <= rejected["n"] <= 4 and rejected["share"] == rejected["n"] / 4
    # a rejected answer can only lose: never more with the open set on than off
    assert all(on[k][t] <= off[k][t] + 1e-12 for k in on for t in on[k])


def test_a_rejected_answer_is_a_miss(service_runs):
    """With every answer rejected, nothing counts with the open set on; with it off, the answers count as
    when the model's own rejection ran (rejection leaves the ranking alone)."""
    everything, usual = service_runs["depth rejecting all"], service_runs["depth"]
    rejected = everything["rejected"]["ours"]
    assert rejected["n"] == 4 and rejected["share"] == 1.0
    # those rejected that ranked the right object first: all that did, with the open set off
    assert rejected["right_object_first"] == round(
        4 * everything["open_set_off"]["methods"]["ours"]["k1"]["180"]
    )
    for key in ("methods", "view_direction"):
        on = everything[key]["ours"]
        assert all(v == 0.0 for row in on.values() for v in row.values())
        assert everything["open_set_off"][key] == usual["open_set_off"][key]
    assert usual["open_set_off"]["methods"]["ours"]["k22"]["180"] > 0  # so the zeros above could be false
    for obj in everything["per_object"].values():
        assert obj["rejected"]["ours"]["share"] == 1.0


def test_the_command_prints_both_open_set_figures(lmo, shipped, tmp_path, capsys, monkeypatch):
    """`posedesc evaluate --protocol paper` with the rgb model (it crashed: its templates had no depth
    for the local features); the service's printed table says what the open set did."""
    monkeypatch.setenv("POSEDESC_THREADS", "1")
    common = ["--dataset", str(lmo), "--objects", "1,5", "--frames", "8,58", "--methods", "ours"]
    out = tmp_path / "paper.json"
    args = ["evaluate", "--protocol", "paper", "--modality", "rgb", "--model", str(MODELS["rgb"])]
    assert main([*args, *common, "--json", str(out)]) == 0
    assert json.loads(out.read_text())["n_samples"] == 4
    out = tmp_path / "service.json"
    args = ["evaluate", "--modality", "depth", "--model", str(MODELS["depth"]), "--inplane-step", "0"]
    assert main([*args, *common, "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    s = json.loads(out.read_text())
    assert "open set off (rejected answers scored as ranked):" in printed
    assert f"{s['rejected']['ours']['n']} of 4 queries rejected" in printed
    assert np.isclose(s["rejected"]["ours"]["share"], s["rejected"]["ours"]["n"] / 4)
