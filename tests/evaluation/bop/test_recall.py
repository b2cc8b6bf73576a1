"""Recall and AR as BOP19 scores them (`evaluation.bop.recall`), on hand-counted cases."""

import numpy as np
import pytest

from evaluation.bop.recall import MSPD_THRESHOLDS, MSSD_THRESHOLDS, VSD_TAUS, bop_matches, bop_recall, recall


def test_bop19_thresholds():
    assert MSSD_THRESHOLDS.tolist() == pytest.approx([0.05 * k for k in range(1, 11)])
    assert MSPD_THRESHOLDS.tolist() == [5.0 * k for k in range(1, 11)]
    assert len(VSD_TAUS) == 10 and VSD_TAUS[0] == 0.05 and VSD_TAUS[-1] == 0.5


def test_perfect_estimates_score_one_and_missing_ones_zero():
    n, d = 4, np.array([100.0, 150.0, 80.0, 200.0])
    perfect = bop_recall(np.zeros(n), np.zeros(n), d, 640, np.zeros((n, 10)))
    assert perfect.ar == 1.0 and perfect.ar_vsd == 1.0
    missing = bop_recall(np.full(n, np.nan), np.full(n, np.nan), d, 640, np.full((n, 10), np.nan))
    assert missing.ar == 0.0 and missing.vsd is not None and missing.vsd.shape == (10, 10)
    assert bop_recall(np.full(n, np.inf), np.full(n, np.inf), d, 640).ar == 0.0


def test_recall_counts_strictly_below_each_threshold_over_targets_pooled():
    """Target 1: MSSD 0.12 d (right from 0.15 d on: 8 of 10), MSPD 25 px in a 1280 px wide image
    (thresholds 10..100 px: right from 30: 8 of 10); target 2 has no estimate."""
    r = bop_recall([12.0, np.nan], [25.0, np.nan], [100.0, 50.0], 1280)
    assert r.mssd.tolist() == [0.0, 0.0] + [0.5] * 8
    assert r.mspd.tolist() == [0.0, 0.0] + [0.5] * 8
    assert r.ar_mssd == pytest.approx(0.4) and r.ar_mspd == pytest.approx(0.4)
    assert r.vsd is None and r.ar_vsd is None and r.ar == pytest.approx(0.4)  # no depth: two parts
    exactly = bop_recall([10.0], [10.0], [100.0], 640)  # at 0.1 d and at 10 px: not below
    assert exactly.mssd[1] == 0.0 and exactly.mssd[2] == 1.0 and exactly.mspd[1] == 0.0


def test_ar_is_the_mean_of_the_three_with_depth():
    """VSD error 0.2 at every tau: right for thresholds 0.25..0.5, 6 of 10."""
    r = bop_recall([0.0], [0.0], [100.0], 640, np.full((1, 10), 0.2))
    assert r.ar_vsd == pytest.approx(0.6)
    assert r.ar == pytest.approx((1.0 + 1.0 + 0.6) / 3)


def test_bad_input_is_a_clear_error():
    with pytest.raises(ValueError, match="at least one target"):
        recall([], MSSD_THRESHOLDS)
    with pytest.raises(ValueError, match="taus"):
        bop_recall([0.0], [0.0], [100.0], 640, np.zeros((1, 3)))


def test_bop_matching_takes_estimates_by_score_each_to_its_best_free_instance():
    """Two instances; estimate a (best score) fits instance 0 at 4 and 1 at 6, estimate b fits 0 at 5
    and 1 at 30, and a third estimate c (lowest score) fits 1 perfectly but only two estimates count."""
    scores = [0.9, 0.5, 0.1]
    errors = np.array([[4.0, 6.0], [5.0, 30.0], [np.nan, 0.0]])
    found = bop_matches(scores, errors, [5.0, 10.0, 50.0])
    # th 5: a takes 0; b's best free is 1 at 30, too far. th 10: the same. th 50: b takes 1.
    assert found.tolist() == [[True, False], [True, False], [True, True]]
    # Scores decide the order: b first takes 0 (at 5, below 10); a then takes 1 (at 6).
    assert bop_matches([0.5, 0.9, 0.1], errors, [10.0]).tolist() == [[True, True]]
    assert not bop_matches([0.9], np.array([[np.nan]]), [1e9]).any()  # nan never matches
    with pytest.raises(ValueError, match="estimates"):
        bop_matches([0.9, 0.1], np.zeros((3, 2)), [5.0])
