"""The detection's confidence and what it reports: how sure a detection is (`confidence`) and whether it is
said at all (`reported`), at most `max_detections` a frame."""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import lru_cache

from service.detection import agree
from service.detection.found import DEPTH_PART, Detection, Frame, Proposal
from service.pipeline.answer import Result
from service.settings import Settings

log = logging.getLogger("service")

#: the share of its visible points a detection from a part of a depth segment larger than any registered
#: object (touching objects that real depth joins: a guess at where one object ends) needs its depth fit to
#: explain (`Settings.detect_depth_fit_floor`, if higher, otherwise). 0.6: chosen on YCB-V video 0000 (real
#: depth): its parts, none of them a registered object there, were named at fits of 0.32-0.55 (quartiles);
#: 0.6 removes 49 of those 50 false detections (LM-O's validation frames: no instance lost); chosen
#: leave-one-video-out it did worse on the video left out (docs/experiments.md)
PART_FIT_FLOOR = 0.6


@dataclass(frozen=True)
class Report:
    """The detections a frame reports, most confident first: those `reported` at the frame's floors
    (`floors`), at most the query's `max_detections`."""

    settings: Settings
    name: str = "report"

    @classmethod
    def build(cls, settings: Settings) -> Report:
        return cls(settings)

    def __call__(self, frame: Frame) -> Frame:
        at = floors(self.settings, frame.d.depth is not None)
        shown = [x for x in frame.detections if reported(x, frame.q.min_confidence, at)]
        return replace(frame, detections=tuple(shown[: frame.q.max_detections]))


@dataclass(frozen=True)
class Floors:
    """What a detection needs to be reported when no `min_confidence` is asked: `confidence`, from a colour
    proposal; `depth_fit`, the share of its visible points its depth fit explains (`part_fit` from a part of a
    depth segment: `service.detection.found.DEPTH_PART`); `colour_distance`, at most
    this far from its object's colours (`service.detection.agree`; None: no ceiling)."""

    confidence: float
    depth_fit: float = 0.0
    colour_distance: float | None = None
    part_fit: float = 0.0


def floors(settings: Settings, depth: bool) -> Floors:
    """A frame's `Floors`. A colour frame whose confidences are weighed by their colours
    (`agree.COLOUR_WEIGHT` > 0) has its own confidence floor, `Settings.detect_rgb_floor`; a frame with depth
    has `Settings.detect_floor`, `Settings.detect_depth_fit_floor` (`PART_FIT_FLOOR` for a part of a depth
    segment, if higher) and, its detections not weighed, a ceiling on their colour distance
    (`Settings.detect_colour_ceiling`)."""
    if depth:
        ceiling = settings.detect_colour_ceiling if settings.detect_colour_ceiling < 2 else None
        return Floors(
            settings.detect_floor,
            depth_fit=settings.detect_depth_fit_floor,
            part_fit=max(settings.detect_depth_fit_floor, PART_FIT_FLOOR),
            colour_distance=ceiling,
        )
    weighed = agree.COLOUR_WEIGHT > 0
    return Floors(settings.detect_rgb_floor if weighed else settings.detect_floor)


#: the model metadata key of a calibrated detection confidence (`DetectConfidence`,
#: written by `scripts/calibrate_detections.py`)
DETECT_KEY = "detect_confidence"


@dataclass(frozen=True)
class DetectConfidence:
    """A model's calibrated confidence of a detection from a depth segment: the chance that it names the
    right object there, from the share of the object's visible surface the depth explains at its fitted pose
    (`Fit.score`): 1 / (1 + exp(slope * (score - midpoint))), a logistic fit on real-depth videos'
    detections (`scripts/calibrate_detections.py`; the figures per video, fitted on the others:
    docs/experiments.md, "A detection's confidence on real depth"). The verifier's confidence says how near
    the best template is; on real depth it spread over 0.3-0.5 for right and wrong detections alike (none
    reached 0.5, so `min_confidence` 0.5 found nothing on any video), and beside the fit its weight changed
    tenfold from one video to the next."""

    slope: float
    midpoint: float

    def __call__(self, fit: float) -> float:
        z = self.slope * (fit - self.midpoint)
        return 1.0 / (1.0 + math.exp(max(min(z, 700.0), -700.0)))

    def to_json(self) -> dict[str, float]:
        return {"slope": self.slope, "midpoint": self.midpoint}


def read_detect_confidence(meta: Mapping[str, str]) -> DetectConfidence | None:
    """A model's `DetectConfidence` from its metadata; None without one (or an unusable one)."""
    return _parsed(meta.get(DETECT_KEY) or "")


@lru_cache(maxsize=16)  # read once per model, not once per detection
def _parsed(text: str) -> DetectConfidence | None:
    if not text:
        return None
    try:
        raw = json.loads(text)
        return DetectConfidence(float(raw["slope"]), float(raw["midpoint"]))
    except (ValueError, TypeError, KeyError) as e:
        log.warning("unusable %s metadata (%s): the verifier's confidence stands", DETECT_KEY, e)
        return None


def confidence(result: Result, p: Proposal, calibrated: DetectConfidence | None = None) -> float:
    """A detection's confidence: the verifier's in its best answer, times the objectness network's score
    for a colour proposal. Measured on the validation frames (docs/experiments.md), the verifier's
    confidence alone ranks a proposal that it screened at nine places too high: the ranking by the
    product had AP50 0.70 against 0.54 by the verifier's and 0.67 by the network's. A depth segment's
    (or part's) detection fitted to the depth, with the verifying model's `calibrated` confidence: that."""
    verified = float(result.confidences[0] or 0.0)
    if p.source == "colour":
        return verified * p.score
    fit = result.fits[0] if result.fits else None
    if calibrated is None or fit is None or fit.failed:
        return verified
    return calibrated(fit.score)


def reported(x: Detection, min_confidence: float | None, at: Floors) -> bool:
    """Whether a detection is reported: its confidence at least `min_confidence` when given; else its pose
    fitted to the frame's depth explaining at least `at.depth_fit` of its visible points (a detection not
    fitted passes), its colours within `at.colour_distance` of its object's (one not measured passes), and
    then, from a colour proposal, its confidence at least `at.confidence`, from depth, accepted by the
    model's open-set verdict (the verdict alone accepted nearly every colour proposal: ten a frame where no
    registered object was)."""
    fit = x.result.fits[0] if x.result.fits else None
    if fit is not None and fit.failed:  # an error is never an answer, whatever is asked
        return False
    if min_confidence is not None:
        return x.confidence >= min_confidence
    if fit is not None and fit.score < (at.part_fit if x.proposal.source == DEPTH_PART else at.depth_fit):
        return False
    ceiling, distance = at.colour_distance, x.colour_distance
    if ceiling is not None and distance is not None and distance > ceiling:
        return False
    if x.proposal.source == "colour":
        return x.confidence >= at.confidence
    return x.result.reason is None
