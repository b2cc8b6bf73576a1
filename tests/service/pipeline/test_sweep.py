"""Roll: `/recognize` estimates the in-plane angle of a rolled object and answers k distinct poses.

The shipped rgb model (trained on upright views: templates over the whole turn come from the settings
here), two procedurally made objects registered through the API, queries rendered as full frames."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from fastapi.testclient import TestClient
from service_helpers import ROOT, frame, frame_fields, png, register, service_settings, wait_ready

from index.geometry.pose import View, wrap_degrees
from index.templates.viewpoints import hemisphere
from service.main import create_app
from service.pipeline import refine as refinement

UV = (360.0, 260.0)
LEVEL = 1  # 16 viewpoints: every query below is at one of them
AZ, EL = (float(x) for x in hemisphere(LEVEL)[7])


@pytest.fixture(scope="module")
def shipped_rgb(tmp_path_factory):
    src = ROOT / "models" / "posedesc-rgb.onnx"
    if not src.is_file():
        pytest.skip("no shipped rgb model")
    folder = tmp_path_factory.mktemp("shipped")
    shutil.copy(src, folder)
    return folder


def serve(tmp_path_factory, models, l_shape, t_shape, **settings):
    """A service with L and T registered. The pose fit is off (`pose_fit`: tests/service/pipeline/test_fit.py):
    these tests read the templates' roll, which the fit would move off the grid."""
    data = tmp_path_factory.mktemp("data")
    settings = {"pose_fit": 0, **settings}
    client = TestClient(create_app(service_settings(data, models, level=LEVEL, **settings)))
    client.__enter__()
    wait_ready(client)
    for mesh, name in ((l_shape, "L"), (t_shape, "T")):
        register(client, mesh, name)
    return client


@pytest.fixture(scope="module")
def whole_turn(tmp_path_factory, shipped_rgb, l_shape, t_shape):
    """Templates every 30° over the whole turn (a setting: the shipped model's metadata has no step)."""
    c = serve(tmp_path_factory, shipped_rgb, l_shape, t_shape, inplane_step=30, inplane_max=180)
    yield c
    c.__exit__(None, None, None)


def ask(client, renderer, mesh, view: View, **data) -> dict:
    rgb, _ = frame(renderer, mesh, view, UV, wall_mm=1500.0)
    fields = frame_fields(UV, distance_mm=view.distance, **data)
    r = client.post("/recognize", files={"rgb": ("f.png", png(rgb))}, data=fields)
    assert r.status_code == 200, r.text
    return r.json()


def roll_error(match: dict, phi: float) -> float:
    return abs(float(wrap_degrees(match["inplane"] - phi)))


@pytest.mark.parametrize("phi", [60.0, -120.0, 75.0])
def test_the_answer_carries_the_roll(whole_turn, renderer, l_shape, phi):
    best = ask(whole_turn, renderer, l_shape, View(AZ, EL, phi, 600.0))["best"]
    assert best["name"] == "L"
    assert (best["azimuth"], best["elevation"]) == pytest.approx((AZ, EL), abs=1e-3)
    assert roll_error(best, phi) < 30.0, best  # within the templates' step
    assert -180.0 < best["inplane"] <= 180.0


def test_k_answers_are_distinct_viewpoints(whole_turn, renderer, l_shape):
    body = ask(whole_turn, renderer, l_shape, View(AZ, EL, 40.0, 600.0), k=20)
    keys = [(m["object_id"], m["azimuth"], m["elevation"]) for m in body["matches"]]
    assert len(keys) == 20 and len(set(keys)) == 20  # 12 in-plane variants each: 240 templates searched
    distances = [m["distance"] for m in body["matches"]]
    assert distances == sorted(distances)


def test_query_turns_refine_the_roll(tmp_path_factory, shipped_rgb, renderer, l_shape, t_shape):
    """Templates every 30°, the query also turned by 10° and 20°: a roll between templates is found
    on the turn that brings it onto one, and answered as that template's angle plus the turn."""
    c = serve(
        tmp_path_factory, shipped_rgb, l_shape, t_shape, inplane_step=30, inplane_max=180, query_turns=3
    )
    try:
        for phi in (70.0, -40.0):
            best = ask(c, renderer, l_shape, View(AZ, EL, phi, 600.0))["best"]
            # within one turn's step (10 deg; the templates' alone: 30): the shipped model's mask trims the
            # render's edge, and the neighbouring turn can win by a hair
            assert best["name"] == "L" and roll_error(best, phi) <= 10.0 + 1e-6, (phi, best)
    finally:
        c.__exit__(None, None, None)


def answers_to_rolls(tmp_path_factory, models, renderer, l_shape, t_shape, phis, **settings) -> list[dict]:
    """What `/recognize` answers for the L rolled by each of `phis`, from a service with templates every
    30° over the whole turn and `settings`."""
    c = serve(tmp_path_factory, models, l_shape, t_shape, inplane_step=30, inplane_max=180, **settings)
    try:
        answers = [ask(c, renderer, l_shape, View(AZ, EL, phi, 600.0)) for phi in phis]
    finally:
        c.__exit__(None, None, None)
    return answers


def test_refinement_finds_a_roll_between_templates(
    tmp_path_factory, shipped_rgb, renderer, l_shape, t_shape, monkeypatch
):
    """Templates every 30°, no query turns: an object rolled 10° (or -50°...) is 10° from the nearest
    template's roll, so without refinement no answer's roll is exact; the refinement compares the best
    answers at their roll +- 10° too, finds it for many and is never worse than the nearest template.
    The refinement's constants are the stage's: set here before each service builds its pipelines."""
    phis = (10.0, -50.0, 100.0, 160.0, -110.0, 40.0, -80.0, 130.0, -170.0, 70.0)  # 10° off a template
    errors: dict[int, list[float]] = {}
    for refine in (0, 5):
        monkeypatch.setattr(refinement, "ROLL_REFINE", refine)
        answers = answers_to_rolls(tmp_path_factory, shipped_rgb, renderer, l_shape, t_shape, phis)
        errors[refine] = []
        for phi, answer in zip(phis, answers, strict=True):
            best = answer["best"] or answer["matches"][0]  # judged unknown or not: the nearest answer
            assert best["name"] == "L" or not refine, (phi, best)  # unrefined, one was the T
            errors[refine].append(roll_error(best, phi) if best["name"] == "L" else 180.0)
    assert min(errors[0]) >= 10.0 - 1e-6, errors  # the templates' rolls only
    # measured: refined, the model shipped at 9495db2 found 7 of the 10 exactly, the fine-tuned mask's 6;
    # the others stay on the nearest template's side (10° off); unrefined, one or two were the T
    assert max(errors[5]) <= 10.0 + 1e-6 and sum(e < 1e-3 for e in errors[5]) >= 4, errors


def test_a_second_round_halves_the_turn(
    tmp_path_factory, shipped_rgb, renderer, l_shape, t_shape, monkeypatch
):
    """Templates every 30°: an object rolled 15° off a template is 5° from any roll one round reaches
    (the template's, +- 10°); a second round turns by +- 5° from there and can land on it."""
    phis = (15.0, -45.0, 105.0, 165.0, -105.0, 45.0, -75.0, 135.0)  # 15° off a template
    errors: dict[int, list[float]] = {}
    monkeypatch.setattr(refinement, "ROLL_REFINE", 5)
    for rounds in (1, 2):
        monkeypatch.setattr(refinement, "REFINE_ROUNDS", rounds)
        answers = answers_to_rolls(tmp_path_factory, shipped_rgb, renderer, l_shape, t_shape, phis)
        errors[rounds] = []
        for phi, answer in zip(phis, answers, strict=True):
            best = answer["best"]
            assert best is not None and best["name"] == "L", (phi, best)
            errors[rounds].append(roll_error(best, phi))
    assert min(errors[1]) >= 5.0 - 1e-6, errors  # one round: the templates' rolls +- 10° only
    # measured (shipped model of c51f601): one round 5° off for all 8, two rounds exact for all 8
    assert max(errors[2]) <= 5.0 + 1e-6 and sum(e < 1e-3 for e in errors[2]) >= 6, errors


def test_refinement_scores_each_pose_once(whole_turn, renderer, l_shape, monkeypatch):
    """The roll sweep compares the best answers at every template roll, the refinement their neighbouring
    viewpoints and turned rolls: a pose the re-ranking or the sweep scored already, or a neighbour two
    answers share, is not computed again (same template, same cut of the query: the same score), and
    each stage gets the scores of all it asked for."""
    from service.pipeline.score import LocalScore

    asked: list[list[tuple[tuple[int, float, float], float]]] = []
    computed: list[int] = []
    pairs, table = LocalScore.pairs, LocalScore.table

    def counting(self, poses):
        before = self.computed
        out = pairs(self, poses)
        asked.append(list(poses))
        computed.append(self.computed - before)
        assert out.shape == (len(poses),) and np.isfinite(out).all()
        return out

    def counting_table(self, keys, rolls):
        before = self.computed
        out = table(self, keys, rolls)
        asked.append([(k, r) for k in keys for r in rolls])
        computed.append(self.computed - before)
        assert out.shape == (len(keys), len(rolls)) and np.isfinite(out).all()
        return out

    monkeypatch.setattr(LocalScore, "pairs", counting)
    monkeypatch.setattr(LocalScore, "table", counting_table)
    answer = ask(whole_turn, renderer, l_shape, View(AZ, EL, 40.0, 600.0))
    assert (
        answer["matches"] and len(asked) == 3
    )  # the re-ranking, the roll sweep (one query turn), the refinement
    first, swept, refined = asked
    assert len(swept) == 12 * min(150, len(first))  # the best 150 at each of the 12 template rolls
    assert computed[0] == len(set(first))  # every candidate once
    assert computed[1] == len(set(swept) - set(first))  # the sweep: only what the re-ranking did not score
    seen = set(first) | set(swept)
    assert refined and computed[2] == len(set(refined) - seen)  # each new pose once, none scored before
    assert set(refined) & seen  # (the refinement does ask again for poses scored before: its own)


def test_the_sweep_finds_the_roll_the_descriptor_missed(
    tmp_path_factory, shipped_rgb, renderer, l_shape, t_shape, monkeypatch
):
    """`ROLL_SWEEP`: every answer the descriptor hands the re-ranking is given a roll 90° off its own (as
    for an occluded object, whose viewpoint the descriptor finds but not its roll). Without the sweep
    the best answer stays far off (the refinement turns by +- 10° only); with every answer swept (each
    compared at every template roll of its viewpoint) the right pose wins."""
    from dataclasses import replace

    from index.store.search import Snapshot

    answers = Snapshot.answers

    def turned(self, *args, **kwargs):
        return [
            replace(m, inplane=float(wrap_degrees(m.inplane + 90.0))) for m in answers(self, *args, **kwargs)
        ]

    monkeypatch.setattr(Snapshot, "answers", turned)
    phis = (0.0, 60.0, -120.0)  # on a template's roll
    errors = {}
    for sweep in (0, 1000):
        found = answers_to_rolls(
            tmp_path_factory, shipped_rgb, renderer, l_shape, t_shape, phis, roll_sweep=sweep
        )
        errors[sweep] = [roll_error(a["matches"][0], phi) for phi, a in zip(phis, found, strict=True)]
    # measured: 120, 30, 30° off (the refinement's 10° turns cannot bring 90° back; other poses win)
    assert min(errors[0]) >= 20.0, errors
    assert max(errors[1000]) < 1e-3, errors


def test_turns_of_an_upright_store_span_the_whole_turn(
    tmp_path_factory, shipped_rgb, renderer, l_shape, t_shape
):
    """Upright templates only (a legacy model's default) and 4 turns of the query (0, 90, 180, 270°):
    an object rolled by 90° is found upright on the turn by 90°, so the answer says +90, not -90."""
    c = serve(tmp_path_factory, shipped_rgb, l_shape, t_shape, inplane_step=0, query_turns=4)
    try:
        assert c.get("/readyz").json()["templates"]["rgb"] == 2 * 16
        for phi in (90.0, -90.0):
            best = ask(c, renderer, l_shape, View(AZ, EL, phi, 600.0))["best"]
            assert best["name"] == "L" and roll_error(best, phi) < 1e-3, (phi, best)
    finally:
        c.__exit__(None, None, None)


def test_upright_answers_say_inplane_zero(tmp_path_factory, shipped_rgb, renderer, l_shape, t_shape):
    c = serve(tmp_path_factory, shipped_rgb, l_shape, t_shape, inplane_step=0)
    try:
        body = ask(c, renderer, l_shape, View(AZ, EL, 0.0, 600.0), k=10)
        assert {m["inplane"] for m in body["matches"]} == {0.0}
        assert body["best"]["name"] == "L"
        assert np.allclose((body["best"]["azimuth"], body["best"]["elevation"]), (AZ, EL), atol=1e-3)
    finally:
        c.__exit__(None, None, None)


@pytest.fixture(scope="module")
def trunk_model(tmp_path_factory):
    """A model with local features (a pretrained trunk: `index.features.embed.LOCAL_NAME`) and templates every
    30° over the whole turn in its metadata; its head untrained (re-ranking does not use it)."""
    torch = pytest.importorskip("torch")
    from training.export import export_onnx
    from training.model import DescriptorNet, NetConfig

    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("trunk")
    export_onnx(DescriptorNet(NetConfig("rgb", 32, arch="trunk")), folder / "posedesc-rgb.onnx", 200.0,
                {"inplane_step": "30.0"})  # fmt: skip
    return folder


def test_answers_are_reranked_by_local_features(tmp_path_factory, trunk_model, renderer, l_shape, t_shape):
    c = serve(tmp_path_factory, trunk_model, l_shape, t_shape, rerank=50)
    try:
        for phi in (60.0, -150.0):
            body = ask(c, renderer, l_shape, View(AZ, EL, phi, 600.0), k=5)
            best = body["best"]
            assert "rerank" in body["timings_ms"]
            assert best["name"] == "L" and roll_error(best, phi) < 1e-3, (phi, best)
            assert (best["azimuth"], best["elevation"]) == pytest.approx((AZ, EL), abs=1e-3)
            distances = [m["distance"] for m in body["matches"]]
            assert distances == sorted(distances) and len(body["matches"]) == 5
    finally:
        c.__exit__(None, None, None)
    off = serve(tmp_path_factory, trunk_model, l_shape, t_shape, rerank=0)
    try:
        body = ask(off, renderer, l_shape, View(AZ, EL, 60.0, 600.0), k=5)
        assert "rerank" not in body["timings_ms"]
    finally:
        off.__exit__(None, None, None)
