"""Recall and AR as BOP19 scores them, from per-target errors (`index.geometry.pose_error`: MSSD, MSPD, VSD).

Targets are pooled over the whole dataset (not averaged per object); a missing estimate (nan or inf) counts
as wrong at every threshold, as BOP counts it. `bop_matches` is BOP's matching of scored estimates to
instances of one object in one image."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from index.geometry.pose_error import missing_as_inf, within

_STEPS = np.round(np.arange(1, 11) * 0.05, 2)  # 0.05, 0.10, ..., 0.50
#: BOP19's thresholds: MSSD's are fractions of the object's diameter; MSPD's are pixels in a 640 px wide
#: image (scaled by width / 640); VSD's taus are fractions of the diameter, its thresholds on the error.
MSSD_THRESHOLDS = _STEPS
MSPD_THRESHOLDS = np.arange(5.0, 51.0, 5.0)
MSPD_REFERENCE_WIDTH = 640.0
VSD_TAUS = _STEPS
VSD_THRESHOLDS = _STEPS


def recall(errors: np.ndarray | Sequence[float], thresholds: np.ndarray) -> np.ndarray:
    """The fraction of targets whose error is strictly below each threshold; a target without an estimate
    (nan or inf) is wrong at every threshold. errors (N,), thresholds (T,) or per target (N, T) -> (T,)."""
    e = missing_as_inf(errors)
    if e.ndim != 1 or len(e) == 0:
        raise ValueError(f"recall needs one error per target, at least one target; got shape {e.shape}")
    th = np.asarray(thresholds, float)
    return within(e[:, None], th if th.ndim == 2 else th[None, :]).mean(axis=0)


@dataclass(frozen=True)
class BopRecall:
    """Recall per BOP19 threshold: mssd (10,), mspd (10,), vsd (taus 10, thresholds 10) or None."""

    mssd: np.ndarray
    mspd: np.ndarray
    vsd: np.ndarray | None = None

    @property
    def ar_mssd(self) -> float:
        return float(self.mssd.mean())

    @property
    def ar_mspd(self) -> float:
        return float(self.mspd.mean())

    @property
    def ar_vsd(self) -> float | None:
        return None if self.vsd is None else float(self.vsd.mean())

    @property
    def ar(self) -> float:
        """The average recall: the mean of AR_VSD, AR_MSSD and AR_MSPD (the latter two without depth)."""
        parts = [self.ar_mssd, self.ar_mspd] + ([] if self.ar_vsd is None else [self.ar_vsd])
        return float(np.mean(parts))


def bop_recall(
    mssd_errors: np.ndarray | Sequence[float],
    mspd_errors: np.ndarray | Sequence[float],
    diameters: np.ndarray | Sequence[float],
    image_width: float,
    vsd_errors: np.ndarray | None = None,
) -> BopRecall:
    """BOP19's recalls over all targets pooled (not per object), one error per target (nan: no estimate):
    mssd_errors (N,) mm, mspd_errors (N,) px, diameters (N,) mm, vsd_errors (N, len(VSD_TAUS)) at the taus
    `VSD_TAUS * diameter`. Matching estimates to targets (BOP keeps the best-scored) is the caller's."""
    d = np.asarray(diameters, float)
    mssd_r = recall(mssd_errors, d[:, None] * MSSD_THRESHOLDS[None, :])
    mspd_r = recall(mspd_errors, MSPD_THRESHOLDS * image_width / MSPD_REFERENCE_WIDTH)
    if vsd_errors is None:
        return BopRecall(mssd_r, mspd_r)
    v = np.asarray(vsd_errors, float)
    if v.shape != (len(d), len(VSD_TAUS)):
        raise ValueError(f"vsd_errors must be (targets, {len(VSD_TAUS)} taus); got {v.shape}")
    return BopRecall(mssd_r, mspd_r, np.stack([recall(v[:, i], VSD_THRESHOLDS) for i in range(v.shape[1])]))


def bop_matches(
    scores: np.ndarray | Sequence[float], errors: np.ndarray, thresholds: np.ndarray | Sequence[float]
) -> np.ndarray:
    """BOP's matching of one image's estimates of one object to its G annotated instances, at each
    threshold: only the G best-scored estimates count; in descending score, each takes the still
    unmatched instance it fits best, when that error is below the threshold. scores (E,), errors (E, G)
    (nan: not computed, never matches), thresholds (T,) -> found (T, G) bool. The count of found targets
    over all images, divided by the count of targets, is `recall`'s figure with several estimates."""
    e = missing_as_inf(errors)
    if e.ndim != 2 or len(e) != len(scores):
        raise ValueError(f"errors must be (estimates {len(scores)}, instances); got shape {e.shape}")
    n_gt = e.shape[1]
    order = np.argsort(-np.asarray(scores, float), kind="stable")[:n_gt]
    found = np.zeros((len(thresholds), n_gt), bool)
    for k, th in enumerate(thresholds):
        for i in order:
            free = np.where(found[k], np.inf, e[i])
            j = int(np.argmin(free))
            if free[j] < th:
                found[k, j] = True
    return found
