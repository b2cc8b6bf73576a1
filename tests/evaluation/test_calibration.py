"""The calibration math of open-set rejection (`evaluation.calibration`) on scores made here."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.calibration import (
    code_digest,
    confidence,
    fit_logistic,
    keep_threshold,
    rejection_curve,
    youden_threshold,
)


def test_logistic_fit_recovers_the_curve_it_was_drawn_from():
    rng = np.random.default_rng(0)
    s = rng.uniform(0, 2, 20000)
    right = rng.random(len(s)) < confidence(s, 6.0, 0.8)
    slope, midpoint = fit_logistic(s, right)
    assert slope == pytest.approx(6.0, rel=0.1)
    assert midpoint == pytest.approx(0.8, abs=0.02)


def test_logistic_weights_move_the_midpoint():
    # the same scores; weighing the wrong ones up makes a score less likely to be right
    s = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8])
    right = np.array([1, 1, 1, 0, 1, 0, 0, 0], bool)
    _, even = fit_logistic(s, right)
    _, heavy = fit_logistic(s, right, np.where(right, 1.0, 4.0))
    assert heavy < even


def test_separable_scores_give_a_finite_steep_fit():
    slope, midpoint = fit_logistic(np.array([0.1, 0.2, 0.8, 0.9]), np.array([1, 1, 0, 0], bool))
    assert np.isfinite(slope) and slope > 5 and 0.2 < midpoint < 0.8


def test_youden_threshold_separates_and_lies_between_the_deciding_scores():
    keep = np.array([0.1, 0.2, 0.3, 0.45])
    reject = np.array([0.4, 0.6, 0.7, 0.8])
    t = youden_threshold(keep, reject)
    # 0.3 | 0.4 keeps 3/4 and accepts 0; 0.45 | 0.6 keeps 4/4 and accepts 1/4: both J = 0.75, first wins
    assert t == pytest.approx(0.35)
    with pytest.raises(ValueError):
        youden_threshold(keep, np.array([]))


def test_keep_threshold_keeps_that_share():
    keep = np.arange(1, 11) / 10
    assert keep_threshold(keep, 0.9) == pytest.approx(0.9)
    assert np.mean(keep <= keep_threshold(keep, 0.25)) >= 0.25


def test_rejection_curve_counts_each_kind():
    c = rejection_curve(
        np.array([0.1, 0.2]), np.array([0.5]), np.array([0.6, 0.9]), np.array([0.15, 0.55, 1.0])
    )
    assert c["rejected_right"] == [0.5, 0.0, 0.0]
    assert c["rejected_wrong"] == [1.0, 0.0, 0.0]
    assert c["rejected_unknown"] == [1.0, 1.0, 0.0]
    # at 0.55: 2 right and 1 wrong of 3 registered accepted, no unknown: precision 2/3
    assert c["precision"][1] == pytest.approx(2 / 3)
    # at 1.0 everything: unknowns weigh as much as all registered patches: (2/3) / (1 + 1)
    assert c["precision"][2] == pytest.approx(1 / 3)


def test_the_code_digest_moves_with_a_constant_of_the_answering_code_and_nothing_else(tmp_path):
    """Collected answers are keyed on it (`scripts/calibrate_reject.py --cache`): a stage's constant changed
    in `service/` gives another digest; a file outside the packages, or not Python, does not."""
    (tmp_path / "service" / "pipeline").mkdir(parents=True)
    (tmp_path / "index").mkdir()
    fit = tmp_path / "service" / "pipeline" / "fit.py"
    fit.write_text("EXPLAINED_WEIGHT = 0.3\n")
    before = code_digest(tmp_path)
    (tmp_path / "service" / "notes.md").write_text("not code")
    (tmp_path / "scripts").mkdir()
    (tmp_path / "scripts" / "probe.py").write_text("x = 1\n")
    assert code_digest(tmp_path) == before
    fit.write_text("EXPLAINED_WEIGHT = 0.5\n")
    assert code_digest(tmp_path) != before
    assert len(code_digest()) == 16  # this checkout's own
