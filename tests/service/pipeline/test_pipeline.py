"""The recognition pipeline's make-up: which stages a model and the settings give it, its timings (each
stage, and the sums older readers know), and a state's pipelines following its settings."""

from __future__ import annotations

import pytest
from service_helpers import ROOT

from index.features.embed import Embedder
from index.templates.register import TemplateConfig
from service.pipeline import SCREEN_RERANK, Pipeline, refine, timings
from service.settings import Settings
from service.state import close_state, load_state

EVERY = ("cut", "mask", "embed", "search", "local", "sweep", "refine")


@pytest.fixture(scope="module")
def shipped_rgb() -> Embedder:
    path = ROOT / "models" / "posedesc-rgb.onnx"
    if not path.is_file():
        pytest.skip("no shipped rgb model")
    return Embedder(path, 1)


@pytest.mark.parametrize(
    ("settings", "names"),
    [
        ({}, EVERY),
        ({"roll_sweep": 0}, ("cut", "mask", "embed", "search", "local", "refine")),
        ({"rerank": 0}, ("cut", "mask", "embed", "search")),
        # upright templates only: one angle, nothing to sweep
        ({"inplane_step": 0}, ("cut", "mask", "embed", "search", "local", "refine")),
    ],
)
def test_the_stages_are_those_the_model_and_the_settings_ask_for(shipped_rgb, settings, names):
    s = Settings(**settings)
    templates = TemplateConfig(s.level, s.inplane_step if "inplane_step" in settings else 30.0, s.inplane_max)
    assert Pipeline.build(s, shipped_rgb, templates).names == names


def test_an_experiment_without_the_refinement_sets_its_constant(shipped_rgb, monkeypatch):
    """The refinement's constants are the stage's (`service.pipeline.refine`), not settings: an experiment
    sets them in its process before the pipeline is built."""
    monkeypatch.setattr(refine, "ROLL_REFINE", 0)
    s = Settings()
    names = Pipeline.build(s, shipped_rgb, TemplateConfig(s.level, 30.0, s.inplane_max)).names
    assert names == ("cut", "mask", "embed", "search", "local", "sweep")


def test_a_screening_reranks_fewer_and_neither_sweeps_nor_refines(shipped_rgb):
    s = Settings()
    screen = Pipeline.screening(s, shipped_rgb, TemplateConfig(s.level, 30.0, s.inplane_max))
    assert screen.names == ("cut", "mask", "embed", "search", "local") and screen.fit is None
    assert screen.settings.rerank == SCREEN_RERANK


def test_a_model_without_mask_or_local_features_only_cuts_embeds_and_searches(posedesc_models):
    e = Embedder(posedesc_models / "posedesc-rgb.onnx", 1)
    assert Pipeline.build(Settings(), e, TemplateConfig(1, 30.0, 180.0)).names == ("cut", "embed", "search")


def test_timings_give_each_stage_then_the_sums_then_the_total():
    spent = {"cut": 0.001, "mask": 0.002, "embed": 0.003, "search": 0.004, "local": 0.01, "refine": 0.005}
    t = timings(spent, 0.03, 0.002)
    assert list(t) == ["decode", *spent, "patch", "rerank", "total"]
    assert t["patch"] == pytest.approx(3.0) and t["rerank"] == pytest.approx(15.0)
    assert t["total"] == pytest.approx(32.0)
    plain = timings({"cut": 0.001, "embed": 0.003, "search": 0.004}, 0.01, None)
    assert list(plain) == ["cut", "embed", "search", "patch", "total"]  # no decode, no re-ranking


def test_a_states_pipelines_are_built_once_and_follow_its_settings(tmp_path, posedesc_models):
    state = load_state(Settings(data_dir=tmp_path, models_dir=posedesc_models, demo_objects=False, level=1))
    try:
        first = state.pipelines
        assert state.pipelines is first  # built once, not per query
        assert first["rgb"].stages[0].config.offsets == (0.0,)  # type: ignore[attr-defined]
        # an evaluation swaps the settings between queries (`evaluation.openset`): the pipelines follow
        state.settings = state.settings.model_copy(update={"query_turns": 2})
        assert state.pipelines is not first
        assert len(state.pipelines["rgb"].stages[0].config.offsets) == 2  # type: ignore[attr-defined]
    finally:
        close_state(state)
