"""The detection's confidence and what it reports: how sure a detection is (`confidence`) and whether it is
said at all (`reported`), at most `max_detections` a frame."""

from __future__ import annotations

from dataclasses import dataclass, replace

from service.detection.found import Detection, Frame, Proposal
from service.pipeline.answer import Result
from service.settings import Settings


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
        colour_floor, fit_floor = floors(self.settings, frame.d.depth is not None)
        shown = [x for x in frame.detections if reported(x, frame.q.min_confidence, colour_floor, fit_floor)]
        return replace(frame, detections=tuple(shown[: frame.q.max_detections]))


def floors(settings: Settings, depth: bool) -> tuple[float, float]:
    """The floors a frame's detections are reported at when no `min_confidence` is asked: (the confidence a
    detection from a colour proposal needs, the share of its visible points its depth fit must explain).
    A colour frame whose confidences are weighed by their colours (`Settings.detect_colour_weight`,
    `service.detection.agree`) has its own floor, `Settings.detect_rgb_floor`; a frame with depth has
    `Settings.detect_floor` and `Settings.detect_depth_fit_floor`."""
    if depth:
        return settings.detect_floor, settings.detect_depth_fit_floor
    weighed = settings.detect_colour_weight > 0
    return (settings.detect_rgb_floor if weighed else settings.detect_floor), 0.0


def confidence(result: Result, p: Proposal) -> float:
    """A detection's confidence: the verifier's in its best answer, times the objectness network's score
    for a colour proposal. Measured on the validation frames (docs/experiments.md), the verifier's
    confidence alone ranks a proposal that it screened at nine places too high: the ranking by the
    product had AP50 0.70 against 0.54 by the verifier's and 0.67 by the network's."""
    verified = float(result.confidences[0] or 0.0)
    return verified * p.score if p.source == "colour" else verified


def reported(
    x: Detection, min_confidence: float | None, colour_floor: float, depth_fit_floor: float = 0.0
) -> bool:
    """Whether a detection is reported: its confidence at least `min_confidence` when given; else its pose
    fitted to the frame's depth explaining at least `depth_fit_floor` of its visible points (a frame with
    depth, `Settings.detect_depth_fit_floor`; a detection not fitted passes), and then, from a colour
    proposal, its confidence at least `colour_floor` (`floors`), from depth, accepted by
    the model's open-set verdict (the verdict alone accepted nearly every colour proposal: ten a frame
    where no registered object was)."""
    if min_confidence is not None:
        return x.confidence >= min_confidence
    fit = x.result.fits[0] if x.result.fits else None
    if fit is not None and fit.score < depth_fit_floor:
        return False
    if x.proposal.source == "colour":
        return x.confidence >= colour_floor
    return x.result.reason is None
