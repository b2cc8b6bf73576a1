"""The math of open-set rejection (`scripts/calibrate_reject.py`, `service.rejection`): from the best answer's
score (a distance, smaller is closer) of three kinds of validation patches — the right object answered,
a wrong object answered while the right one is registered, an object that is not registered — a threshold
and a confidence curve; the detection confidence's calibration error (`scripts/calibrate_detections.py`);
the metadata a calibration is written into; and the digest of the code that makes the answers (what a cache
of collected answers is keyed on). Pure numpy but for the last two."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np


def fit_logistic(
    scores: np.ndarray, right: np.ndarray, weights: np.ndarray | None = None, iterations: int = 50
) -> tuple[float, float]:
    """P(right | score) = 1 / (1 + exp(slope * (score - midpoint))), by weighted maximum likelihood
    (Newton's method). Returns (slope, midpoint); slope > 0 when smaller scores are more often right.
    A tiny ridge keeps it finite when the two kinds do not overlap."""
    s = np.asarray(scores, float)
    y = np.asarray(right, float)
    w = np.ones_like(s) if weights is None else np.asarray(weights, float)
    centre, scale = float(np.average(s, weights=w)), float(s.std()) or 1.0
    x = np.stack([np.ones_like(s), (s - centre) / scale], axis=1)  # standardised: a well-conditioned Newton
    beta = np.zeros(2)
    ridge = 1e-6 * w.sum() * np.eye(2)
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-np.clip(x @ beta, -30, 30)))
        grad = x.T @ (w * (y - p)) - ridge @ beta
        hess = (x * (w * p * (1 - p))[:, None]).T @ x + ridge
        step = np.linalg.solve(hess, grad)
        beta += step
        if np.abs(step).max() < 1e-9:
            break
    b0, b1 = beta
    slope = -b1 / scale
    if abs(b1) < 1e-12:
        return 0.0, centre
    return float(slope), float(centre - b0 * scale / b1)


def confidence(scores: np.ndarray, slope: float, midpoint: float) -> np.ndarray:
    """The fitted curve (as `service.rejection.Calibration.confidence`)."""
    z = np.clip(slope * (np.asarray(scores, float) - midpoint), -700, 700)
    return 1.0 / (1.0 + np.exp(z))


def youden_threshold(keep: np.ndarray, reject: np.ndarray) -> float:
    """The threshold (accept score <= it) that maximises the share of `keep` accepted minus the share of
    `reject` accepted (Youden's J); half-way between the deciding score and the next one, so a slightly
    different score on the same patch falls on the same side."""
    keep, reject = np.sort(np.asarray(keep, float)), np.sort(np.asarray(reject, float))
    if not len(keep) or not len(reject):
        raise ValueError("a threshold needs scores of both kinds")
    cands = np.unique(np.concatenate([keep, reject]))
    j = np.searchsorted(keep, cands, "right") / len(keep) - np.searchsorted(reject, cands, "right") / len(
        reject
    )
    i = int(np.argmax(j))
    return float(cands[i] + (cands[i + 1] - cands[i]) / 2) if i + 1 < len(cands) else float(cands[i])


def keep_threshold(keep: np.ndarray, share: float) -> float:
    """The smallest threshold that accepts at least `share` of `keep` (e.g. 0.9: 10 % of right answers lost)."""
    keep = np.sort(np.asarray(keep, float))
    return float(keep[min(len(keep) - 1, max(0, int(np.ceil(share * len(keep))) - 1))])


def at_least(threshold: float, decimals: int = 5) -> float:
    """`threshold` written with `decimals` decimals, never below it: the rule's threshold is the statistic of
    an answer it keeps (`keep_threshold`), and rounded down it would reject that answer and every one alike
    (the same patch answered alike in several registered sets: the rgb calibration of before rejected 8.45 %
    of the registered validation patches under a rule of at most 8 %)."""
    out = round(threshold, decimals)
    while out < threshold:
        out = round(out + 10.0**-decimals, decimals)
    return out


def auc(high: np.ndarray, low: np.ndarray) -> float:
    """P(a `high` score above a `low` one), ties half."""
    low = np.sort(low)
    below = np.searchsorted(low, high, "left")
    ties = np.searchsorted(low, high, "right") - below
    return float((below + ties / 2).sum() / (len(high) * len(low)))


def rejection_curve(
    right: np.ndarray, wrong: np.ndarray, unknown: np.ndarray, thresholds: np.ndarray
) -> dict[str, list[float]]:
    """At each threshold: the share of each kind rejected (score above it), and the precision and recall
    of the accepted answers (an answer is right when its object is right; recall over the right answers).
    Precision counts unknown patches as often as registered ones (right + wrong), whatever their numbers."""
    t = np.asarray(thresholds, float)

    def rejected(s: np.ndarray) -> np.ndarray:
        s = np.sort(np.asarray(s, float))
        return 1.0 - np.searchsorted(s, t, "right") / max(1, len(s))

    r, w, u = rejected(right), rejected(wrong), rejected(unknown)
    n_reg = len(right) + len(wrong)
    kept_right = (1 - r) * len(right) / max(1, n_reg)  # per registered patch
    kept_wrong = (1 - w) * len(wrong) / max(1, n_reg)
    accepted = kept_right + kept_wrong + (1 - u)  # unknowns weigh as much as all registered patches
    precision = np.where(accepted > 0, kept_right / np.maximum(accepted, 1e-12), 1.0)
    return {
        "threshold": t.tolist(),
        "rejected_right": r.tolist(),
        "rejected_wrong": w.tolist(),
        "rejected_unknown": u.tolist(),
        "precision": precision.tolist(),
        "recall": (1 - r).tolist(),
    }


def calibration_error(p: np.ndarray, right: np.ndarray, bins: int = 5) -> float:
    """The expected calibration error: over `bins` equal bins of the confidence `p`, the share of answers
    in each times how far their mean confidence is from the share of them that were right."""
    p, y = np.asarray(p, float), np.asarray(right, float)
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.digitize(p, edges[1:-1]), 0, bins - 1)
    return float(sum((which == b).mean() * abs(p[which == b].mean() - y[which == b].mean())
                     for b in range(bins) if (which == b).any()))  # fmt: skip


def write_metadata(model: Path, out: Path, props: dict[str, str]) -> None:
    """`model` written to `out` with these metadata entries set (the others kept): only metadata_props
    changes; refused when the graph would (the onnx package)."""
    import onnx

    proto = onnx.load(str(model))
    graph = proto.graph.SerializeToString()
    merged = {p.key: p.value for p in proto.metadata_props} | props
    del proto.metadata_props[:]
    for k, v in merged.items():
        proto.metadata_props.add(key=k, value=v)
    onnx.save(proto, str(out))
    if onnx.load(str(out)).graph.SerializeToString() != graph:
        raise SystemExit(f"{out}: the graph changed while writing the metadata")


def code_digest(
    root: Path = Path(__file__).resolve().parents[1], packages: tuple[str, ...] = ("index", "service")
) -> str:
    """A digest of the Python sources of `packages` under `root` (paths and bytes): the code that makes an
    answer. A stage's constant (`service.pipeline.fit.EXPLAINED_WEIGHT`, say) moves answers without moving
    any setting, so answers collected under other code are not the same answers."""
    h = hashlib.sha256()
    for package in packages:
        for f in sorted((root / package).rglob("*.py")):
            h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes())
    return h.hexdigest()[:16]
