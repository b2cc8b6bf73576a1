"""`service.pipeline.answer.shown`: after the depth re-orders the answers, the open-set verdict is the one of the
answer shown first, on its own statistic; and that statistic is the one the calibration measures on the
answers as the service lists them (`evaluation.openset.best_values`), so a threshold set there is the
threshold the service applies."""

from __future__ import annotations

import numpy as np
import pytest
from service_helpers import calibrated

from evaluation.openset import best_values
from index.features.embed import Embedder
from index.refine.fit import Fit
from index.store import Match
from service.pipeline.answer import Result, shown
from service.pipeline.fit import first, reranked
from service.rejection import Calibration, judge

#: rejects a best answer whose distance less its lead over the nearest other object is above 0.25
CAL = Calibration("descriptor", 0.25, 30.0, 0.25, statistic="lead", weight=0.5)


@pytest.fixture(scope="module")
def embedder(posedesc_models, tmp_path_factory) -> Embedder:
    return calibrated(posedesc_models, tmp_path_factory.mktemp("judged-models"), "depth", {"descriptor": CAL})


def judged(distances: list[tuple[int, float]], explained: list[float]) -> Result:
    """Answers (object, distance), nearest first, judged as `service.pipeline.answer.answer` judges them, and
    fitted with the depth explaining `explained` of each (the first ones)."""
    matches = [Match(o, f"o{o}", 10.0 * i, 20.0, 0.0, d) for i, (o, d) in enumerate(distances)]
    verdict = judge(matches, "descriptor", CAL)
    fits = [Fit(np.eye(3), np.array([0.0, 0.0, 500.0]), s, s, 1, True) for s in explained]
    return Result(
        "posedesc-depth", matches, {}, np.array([0.0, 0.0, 1.0]), 500.0, "descriptor", verdict.confidences,
        verdict.reason, [500.0] * len(matches), fits, statistic=verdict.value, statistics=verdict.values,
    )  # fmt: skip


def test_the_nearest_answer_stands_and_the_one_the_depth_puts_first_is_judged_on_its_own(embedder):
    # object 1 is nearest (0.2, lead 0.1 over object 2: 0.15, accepted); the depth explains object 2 far better
    r = judged([(1, 0.2), (2, 0.3), (3, 0.6)], [0.1, 0.95, 0.1])
    assert r.reason is None and r.statistic == pytest.approx(0.15)
    out = shown(first(reranked(r, 3), 3), embedder, None)
    assert out.matches[0].object_id == 2
    # object 2's own statistic: 0.3, behind object 1 (no lead): above 0.25, so the answer shown is rejected
    assert out.statistic == pytest.approx(0.3) and out.reason is not None
    assert out.confidences[0] == pytest.approx(CAL.confidence(0.3))


def test_an_answer_put_first_is_never_less_far_than_a_rejected_nearest_one(embedder):
    # object 1 and object 2 about as near: object 1's lead is tiny (0.27 > 0.25, rejected); an answer that
    # is not the nearest has no lead, so its statistic is its distance, no smaller: rejected too
    r = judged([(1, 0.27), (1, 0.271), (2, 0.275), (3, 0.9)], [0.0, 0.0, 0.9, 0.0])
    assert r.reason is not None
    out = shown(first(reranked(r, 4), 4), embedder, None)
    assert out.matches[0].object_id == 2 and out.statistic == pytest.approx(0.275) and out.reason is not None
    # a setting that rejects nothing rejects nothing, whichever answer is first
    assert shown(first(reranked(r, 4), 4), embedder, "off").reason is None


def test_without_reordering_the_verdict_is_the_same_object(embedder):
    r = judged([(1, 0.1), (2, 0.3)], [0.9, 0.1])
    assert shown(first(reranked(r, 2), 2), embedder, None) == first(reranked(r, 2), 2)


def test_the_calibration_reads_the_statistic_the_service_judges():
    """The calibration's lists are the service's answers as listed (re-ordered); the statistic it reads of
    the first is what `shown` judges."""
    r = judged([(1, 0.2), (2, 0.3), (1, 0.31), (3, 0.35), (2, 0.5)], [0.1, 0.2, 0.95, 0.3, 0.1])
    out = first(reranked(r, 5), 5)
    ids = np.array([[m.object_id for m in out.matches]])
    dist = np.array([[m.distance for m in out.matches]])
    assert out.matches[0].object_id == 1 and out.matches[0].distance == 0.31
    assert best_values(ids, dist, CAL)[0] == pytest.approx(out.statistics[0])
    assert out.statistics[0] == pytest.approx(0.31 - 0.5 * 0.0)  # object 2 at 0.3 is nearer: no lead
