"""What a calibrated detection confidence reads of each ranked detection (`cues_of`), and what each was
(`cue_outcomes`): the detect protocol's `posedesc.cues`, `scripts/calibrate_detections.py`'s input."""

from __future__ import annotations

from collections.abc import Sequence

from evaluation.detect.score import Hit, Truth, match
from service.detection import Detection


def cues_of(d: Detection) -> dict:
    """What `service.detection.report.DetectConfidence` reads of a detection: its source, the verifier's
    confidence and its depth fit's score (None: not fitted)."""
    fit = d.result.fits[0] if d.result.fits else None
    verifier = d.result.confidences[0] if d.result.confidences else None
    return {
        "source": d.proposal.source,
        "verifier": None if verifier is None else round(float(verifier), 5),
        "fit": None if fit is None or fit.failed else round(float(fit.score), 5),
        "confidence": round(float(d.confidence), 5),
    }


def cue_outcomes(ranked: Sequence[Hit], cues: Sequence[dict], truths: Sequence[Truth]) -> list[dict]:
    """Each ranked hit's cues (`cues_of`) and what it was ("tp", "fp" or "ignored": `match`, by confidence)."""
    matched = match(ranked, truths)
    outcome = {id(h): o for h, o in zip(matched.hits, matched.outcome, strict=True)}
    return [{**c, "outcome": outcome[id(h)]} for h, c in zip(ranked, cues, strict=True)]
