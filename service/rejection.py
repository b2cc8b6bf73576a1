"""Open-set rejection: "none of the registered objects" when the best answer's score says it is no match.

A patch of an object that is not registered still has a nearest template; only its score tells that it is
no match. Each model carries, in its metadata (`reject_above`, written by `scripts/calibrate_reject.py`),
one calibration per kind of distance the service answers with: "local" (the local-feature distance of the
re-ranked answers) or "descriptor" (the descriptor distance, without re-ranking). A calibration holds

- `statistic`: what it thresholds, computed from the answers (`Calibration.values`): "distance", the
  answer's distance; or "lead", the distance less `weight` times the answer's lead over the nearest answer
  of another object (a registered object's best answer is far ahead of every other object's; an unknown
  one's has several objects' answers about as near). Calibrations without it (before "lead") threshold
  the distance;
- `threshold`: above it the best answer is rejected (chosen on the model's validation frames with objects
  left unregistered, see the script);
- `slope`, `midpoint`: the confidence of an answer with statistic s is 1 / (1 + exp(slope * (s -
  midpoint))), a logistic fit on validation answers of whether the top answer was the right object (half of
  them with the object registered, half with it left out: a 1 in 2 chance that a patch shows an unknown);
- `colour` (optional, a `Term`): a frame sent with its camera and the object's centre, in colour, shows
  whether the frame's colours where the best answer's pose puts its object are that object's
  (`index.refine.chroma.chroma_distance`, 0-2: its `colour_distance`). The best answer's statistic then
  adds `weight` times that distance and is judged on the term's own threshold and confidence curve; a
  patch, a shape-only object or a frame without colour is judged on the statistic alone. An unknown object
  named after a registered one has that one's distance and its lead but not its colours: on LM-O's
  validation frames the colours took the unknowns rejected from 63.5 to 71.3 % at the same share of
  registered ones (docs/experiments.md, "The colours in the open set");
- `fit` (optional, a `Term`): a frame sent with its camera, its depth and the object's centre shows how much
  of the best answer's fitted pose the depth leaves unexplained where it could explain it
  (`index.refine.depth.unexplained_of`, 0-1: points hidden by a nearer object, or over a hole in the depth,
  left out). The best answer's statistic then adds `weight` times that share, judged on the term's own
  threshold and curve. An unknown object named after a registered one has its distance and its lead, but
  its surface is not where that one's would be; a registered one half hidden is far from its templates and
  still fits (docs/experiments.md, "The depth fit in the open set");
- `settings`: the settings (and the stages' constants) its answers were made with
  (`service.pipeline.calibration.settings_of`), and `graph`: the network it was measured on
  (`Embedder.graph_digest`); `service.pipeline.calibration.stale` tells the running service when either
  differs from its own, as the scores then differ from those it was calibrated on.

Example (JSON in the metadata): {"local": {"statistic": "lead", "weight": 1.0, "threshold": 0.6, "slope":
9.1, "midpoint": 0.5, "frames": "val", "settings": {"rerank": 400, ...}, ...}, "descriptor": {...}}. The
setting `POSEDESC_REJECT_ABOVE` replaces every model's threshold by a number (on the model's statistic,
the distance without a calibration), or turns rejection off ("off"); confidences are then still the
model's."""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache

from index.features.embed import Embedder
from index.store import Match
from service.settings import Settings

log = logging.getLogger(__name__)

REJECT_KEY = "reject_above"
#: the score an answer's `distance` is: local features when re-ranked, else the descriptor distance
SCORE_KINDS = ("local", "descriptor")
#: what a calibration may threshold (see the module's docstring)
STATISTICS = ("distance", "lead")
#: what a frame may show of the best answer, beside its statistic (`Term`), and how a verdict names it
MEASURES = {"colour": "its colour distance", "fit": "the share of it the depth leaves unexplained"}
#: answers the service ranks to compute a statistic that reads past the best one, whatever k was asked
#: ("lead": the nearest other object's answer is nearly always among them; 40 is what the calibration's
#: answers listed, `evaluation.openset.LISTED`)
LISTED = 40


def served_score(settings: Settings, embedder: Embedder) -> str:
    """The kind of distance the service answers this model's queries with."""
    return "local" if embedder.has_local and settings.rerank > 0 else "descriptor"


@dataclass(frozen=True)
class Term:
    """The best answer's statistic with what the frame shows of it (its colour distance, or the share of its
    surface the depth leaves unexplained): the statistic plus `weight` times that measure, rejected above
    `threshold`, its confidence 1 / (1 + exp(slope * (s - midpoint)))."""

    weight: float
    threshold: float
    slope: float
    midpoint: float

    def confidence(self, value: float) -> float:
        return _logistic(self.slope, self.midpoint, value)

    def to_json(self) -> dict[str, float]:
        return {
            "weight": self.weight,
            "threshold": self.threshold,
            "slope": self.slope,
            "midpoint": self.midpoint,
        }


def _logistic(slope: float, midpoint: float, value: float) -> float:
    z = slope * (value - midpoint)
    return 1.0 / (1.0 + math.exp(min(z, 700.0)))  # exp overflows past ~709


@dataclass(frozen=True)
class Calibration:
    """One score kind's rejection threshold and confidence curve (see the module's docstring)."""

    score: str
    threshold: float
    slope: float
    midpoint: float
    frames: str = "val"
    statistic: str = "distance"
    weight: float = 0.0
    settings: Mapping[str, object] | None = field(default=None, hash=False, compare=False)
    #: the digest of the model graph it was measured on (`Embedder.graph_digest`); None in older ones
    graph: str | None = field(default=None, compare=False)
    #: the best answer's statistic with its colours, where a frame shows them (None: not calibrated)
    colour: Term | None = None
    #: the best answer's statistic with what its depth fit leaves unexplained, where a frame shows it (None:
    #: not calibrated)
    fit: Term | None = None

    def values(self, matches: Sequence[Match]) -> list[float]:
        """Each answer's statistic. "lead": its distance less `weight` times its lead over the nearest
        answer of another object among `matches` (the last one's distance when none is listed: a lead at
        least that large)."""
        if self.statistic == "distance" or not matches:
            return [m.distance for m in matches]
        out = []
        for m in matches:
            others = [o.distance for o in matches if o.object_id != m.object_id]
            nearest = others[0] if others else matches[-1].distance
            out.append(m.distance - self.weight * max(0.0, nearest - m.distance))
        return out

    def confidence(self, value: float) -> float:
        """Chance that an answer with this statistic is the right object (validation frames, logistic)."""
        return _logistic(self.slope, self.midpoint, value)

    def term(self, measure: str) -> Term | None:
        """The term of a measure ("colour" or "fit"; `MEASURES`), None when not calibrated."""
        return {"colour": self.colour, "fit": self.fit}[measure]

    def with_term(self, measure: str, term: Term | None) -> Calibration:
        """This calibration with `term` as its term of `measure` ("colour" or "fit")."""
        return replace(self, colour=term) if measure == "colour" else replace(self, fit=term)

    def describe(self, measure: str | None = None) -> str:
        """What the verdict thresholds (with the term of `measure`, when it has one)."""
        what = (
            f"{self.score} distance"
            if self.statistic == "distance"
            else f"{self.score} distance less {self.weight:g} x its lead over the nearest other object"
        )
        if measure is not None and (term := self.term(measure)) is not None:
            what += f", plus {term.weight:g} x {MEASURES[measure]}"
        return what

    def to_json(self) -> dict[str, object]:
        return {
            "statistic": self.statistic,
            "weight": self.weight,
            "threshold": self.threshold,
            "slope": self.slope,
            "midpoint": self.midpoint,
            "frames": self.frames,
            **({} if self.settings is None else {"settings": dict(self.settings)}),
            **({} if self.graph is None else {"graph": self.graph}),
            **({} if self.colour is None else {"colour": self.colour.to_json()}),
            **({} if self.fit is None else {"fit": self.fit.to_json()}),
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
        out = {
            kind: Calibration(
                kind,
                float(c["threshold"]),
                float(c["slope"]),
                float(c["midpoint"]),
                str(c.get("frames", "val")),
                str(c.get("statistic", "distance")),  # older calibrations threshold the distance
                float(c.get("weight", 0.0)),
                dict(c["settings"]) if c.get("settings") is not None else None,
                str(c["graph"]) if c.get("graph") is not None else None,
                _term(c.get("colour")),
                _term(c.get("fit")),
            )
            for kind, c in raw.items()
            if kind in SCORE_KINDS
        }
        if bad := sorted({c.statistic for c in out.values()} - set(STATISTICS)):
            raise ValueError(f"unknown statistic {bad[0]!r}")
        return out
    except (ValueError, TypeError, KeyError, AttributeError) as e:
        log.warning("%s: unusable %s metadata (%s): no rejection", model, REJECT_KEY, e)
        return {}


def _term(raw: object) -> Term | None:
    """A calibration's term from its JSON (None: it has none)."""
    if raw is None:
        return None
    if not isinstance(raw, Mapping):
        raise ValueError("its term is not an object")
    return Term(*(float(raw[k]) for k in ("weight", "threshold", "slope", "midpoint")))


@dataclass(frozen=True)
class Verdict:
    """Each match's confidence (None without a calibration of its score), when the best answer is rejected
    why (None when it stands), and each match's statistic (`values`: the distance without a calibration),
    the best's (`value`, None without answers) what a later look at the frame adds to (`termed`)."""

    confidences: list[float | None]
    reason: str | None
    values: list[float] = field(default_factory=list)

    @property
    def value(self) -> float | None:
        return self.values[0] if self.values else None


def judge(
    matches: Sequence[Match],
    score: str,
    calibration: Calibration | None,
    setting: float | str | None = None,
) -> Verdict:
    """Whether the best of `matches` (nearest first, `distance` a `score` kind; `LISTED` of them when the
    calibration's statistic reads past the best) is close enough. `setting`: a threshold replacing the
    calibration's, "off" for no rejection, None for the model's."""
    values = [m.distance for m in matches] if calibration is None else calibration.values(matches)
    confidences = [None if calibration is None else calibration.confidence(v) for v in values]
    if not matches:
        return Verdict(confidences, "no object is registered")
    return Verdict(confidences, reason_of(values[0], score, calibration, setting), values)


def reason_of(
    value: float, score: str, calibration: Calibration | None, setting: float | str | None = None
) -> str | None:
    """Why an answer whose statistic is `value` is rejected as the best (None when it stands): `judge`'s
    verdict on an answer that comes first after the answers were judged (the depth's re-ordering)."""
    threshold = None if calibration is None else calibration.threshold
    return _reason(value, threshold, score, calibration, setting)


def termed(
    value: float,
    measure: str,
    measured: float,
    score: str,
    calibration: Calibration,
    setting: float | str | None = None,
) -> tuple[float, str | None]:
    """The best answer's confidence and verdict (`judge`'s reason) once the frame shows `measure` of it
    ("colour": its colour distance; "fit": the share its depth fit leaves unexplained): its statistic
    `value` plus the term's weight times `measured`, on the term's threshold and curve (`calibration.term`,
    which the caller checked). `setting` as `judge` takes it."""
    term = calibration.term(measure)
    assert term is not None  # the caller's check: a calibration without the term judges `value` alone
    total = value + term.weight * measured
    return term.confidence(total), _reason(total, term.threshold, score, calibration, setting, measure)


def _reason(
    value: float,
    threshold: float | None,
    score: str,
    calibration: Calibration | None,
    setting: float | str | None,
    measure: str | None = None,
) -> str | None:
    """Why the best answer, its statistic `value`, is rejected at the calibration's `threshold` (or the
    setting's); None when it stands."""
    if setting == "off":
        return None
    if setting is not None:
        threshold, source = float(setting), "the setting POSEDESC_REJECT_ABOVE"
    elif calibration is not None and threshold is not None:
        source = f"the model's calibration on {calibration.frames} frames"
    else:
        return None
    if value <= threshold:
        return None
    what = f"{score} distance" if calibration is None else calibration.describe(measure)
    return (
        f"no registered object is close enough: the nearest answer's {what} {value:.4g} is above "
        f"{threshold:.4g} ({source})"
    )
