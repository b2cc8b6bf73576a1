"""The detection's confidence and what it reports: how sure a detection is (`confidence`) and whether it is
said at all (`reported`), at most `max_detections` a frame."""

from __future__ import annotations

from dataclasses import dataclass, replace

from service.detection import agree
from service.detection.found import DEPTH_PART, Detection, Frame, Proposal
from service.pipeline.answer import Result
from service.settings import Settings

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


def confidence(result: Result, p: Proposal) -> float:
    """A detection's confidence: the verifier's in its best answer, times the objectness network's score
    for a colour proposal. Measured on the validation frames (docs/experiments.md), the verifier's
    confidence alone ranks a proposal that it screened at nine places too high: the ranking by the
    product had AP50 0.70 against 0.54 by the verifier's and 0.67 by the network's."""
    verified = float(result.confidences[0] or 0.0)
    return verified * p.score if p.source == "colour" else verified


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
