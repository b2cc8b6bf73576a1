"""Open-set rejection: "none of the registered objects" when the best answer's score is too far.

A patch of an object that is not registered still has a nearest template; only its score tells that it is
no match. Each model carries, in its metadata (`reject_above`, written by `scripts/calibrate_reject.py`),
one calibration per kind of score the service answers with: "local" (the local-feature distance of the
re-ranked answers) or "descriptor" (the descriptor distance, without re-ranking). A calibration holds

- `threshold`: above it the best answer is rejected (chosen on the model's validation frames between the
  right object's scores and those of objects left unregistered, see the script);
- `slope`, `midpoint`: the confidence of an answer with score s is 1 / (1 + exp(slope * (s - midpoint))),
  a logistic fit on validation answers of whether the top answer was the right object (half of them
  with the object registered, half with it left out: a 1 in 2 chance that a patch shows an unknown object).

Example (JSON in the metadata): {"local": {"threshold": 1.07, "slope": 9.1, "midpoint": 1.02,
"frames": "val", ...}, "descriptor": {...}}. The setting `POSEDESC_REJECT_ABOVE` replaces every model's
threshold by a number, or turns rejection off ("off"); confidences are then still the model's."""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache

from index.store import Match

log = logging.getLogger(__name__)

REJECT_KEY = "reject_above"
#: the score an answer's `distance` is: local features when re-ranked, else the descriptor distance
SCORE_KINDS = ("local", "descriptor")


@dataclass(frozen=True)
class Calibration:
    """One score kind's rejection threshold and confidence curve (see the module's docstring)."""

    score: str
    threshold: float
    slope: float
    midpoint: float
    frames: str = "val"

    def confidence(self, score: float) -> float:
        """Chance that an answer with this score is the right object (validation frames, logistic)."""
        z = self.slope * (score - self.midpoint)
        return 1.0 / (1.0 + math.exp(min(z, 700.0)))  # exp overflows past ~709

    def to_json(self) -> dict[str, object]:
        return {
            "threshold": self.threshold,
            "slope": self.slope,
            "midpoint": self.midpoint,
            "frames": self.frames,
        }


def read_calibrations(meta: Mapping[str, str], model: str = "model") -> dict[str, Calibration]:
    """The calibrations a model's metadata holds, by score kind; none when it has none (or a bad one:
    logged, the model still serves without rejection)."""
    return _parse(meta.get(REJECT_KEY) or "", model)


@lru_cache(maxsize=16)  # read once per model, not once per request
def _parse(text: str, model: str) -> dict[str, Calibration]:
    if not text:
        return {}
    try:
        raw = json.loads(text)
        return {
            kind: Calibration(
                kind,
                float(c["threshold"]),
                float(c["slope"]),
                float(c["midpoint"]),
                str(c.get("frames", "val")),
            )
            for kind, c in raw.items()
            if kind in SCORE_KINDS
        }
    except (ValueError, TypeError, KeyError, AttributeError) as e:
        log.warning("%s: unusable %s metadata (%s): no rejection", model, REJECT_KEY, e)
        return {}


@dataclass(frozen=True)
class Verdict:
    """Each match's confidence (None without a calibration of its score) and, when the best answer is
    rejected, why (None when it stands)."""

    confidences: list[float | None]
    reason: str | None


def judge(
    matches: Sequence[Match],
    score: str,
    calibration: Calibration | None,
    setting: float | str | None = None,
) -> Verdict:
    """Whether the best of `matches` (nearest first, `distance` a `score` kind) is close enough.
    `setting`: a threshold replacing the calibration's, "off" for no rejection, None for the model's."""
    confidences = [None if calibration is None else calibration.confidence(m.distance) for m in matches]
    if not matches:
        return Verdict(confidences, "no object is registered")
    if setting == "off":
        return Verdict(confidences, None)
    if setting is not None:
        threshold, source = float(setting), "the setting POSEDESC_REJECT_ABOVE"
    elif calibration is not None:
        threshold, source = calibration.threshold, f"the model's calibration on {calibration.frames} frames"
    else:
        return Verdict(confidences, None)
    best = matches[0].distance
    if best <= threshold:
        return Verdict(confidences, None)
    return Verdict(
        confidences,
        f"no registered object is close enough: the nearest answer's {score} distance {best:.4g} is above "
        f"{threshold:.4g} ({source})",
    )
