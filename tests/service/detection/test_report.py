"""`service.detection.report.reported`: what a detection needs to be reported, the depth fit's floor included."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np

from index.refine.fit import Fit, failed_at
from service.detection import agree
from service.detection.found import DEPTH_PART, Detection, Proposal
from service.detection.report import (
    DETECT_KEY,
    PART_FIT_FLOOR,
    DetectConfidence,
    Floors,
    confidence,
    floors,
    read_detect_confidence,
    reported,
)
from service.pipeline.answer import Result
from service.settings import Settings


def detection(
    source: str, confidence: float, fit: float | None, rejected: bool = False, colours: float | None = None
) -> Detection:
    fits = [] if fit is None else [Fit(np.eye(3), np.zeros(3), fit, 0.0, 1, True)]
    result = Result(
        "posedesc-depth", [], {}, np.array([0.0, 0.0, 1.0]), 500.0, "local", [confidence],
        "unknown" if rejected else None, [500.0], fits,
    )  # fmt: skip
    p = Proposal(10.0, 10.0, None, (0.0, 0.0, 20.0, 20.0), 0.9, source)
    return Detection(10.0, 10.0, p.box, confidence, result, p, colour_distance=colours)


def test_with_depth_a_detection_in_other_colours_than_its_objects_is_not_reported():
    at = Floors(0.4, 0.2, 0.25)
    assert reported(detection("depth", 0.9, 0.5, colours=0.1), None, at)
    assert not reported(detection("depth", 0.9, 0.5, colours=0.4), None, at)  # the frame is not its colours
    assert not reported(detection("colour", 0.9, 0.5, colours=0.4), None, at)
    assert reported(detection("depth", 0.9, 0.5, colours=None), None, at)  # a shape: nothing to compare
    assert reported(detection("depth", 0.9, 0.5, colours=0.4), None, Floors(0.4, 0.2, None))
    assert reported(detection("depth", 0.9, 0.5, colours=0.4), 0.5, at)  # min_confidence replaces them all


def test_a_pose_the_depth_does_not_bear_out_is_not_reported():
    assert reported(detection("depth", 0.9, 0.5), None, Floors(0.4, 0.2))
    assert not reported(detection("depth", 0.9, 0.1), None, Floors(0.4, 0.2))  # 10 % of it where depth says
    assert not reported(detection("colour", 0.9, 0.1), None, Floors(0.4, 0.2))
    assert reported(
        detection("depth", 0.9, None), None, Floors(0.4, 0.2)
    )  # not fitted: nothing to bear it out
    assert reported(detection("depth", 0.9, 0.1), None, Floors(0.4, 0.0))  # no depth in the frame: no floor


def test_a_detection_whose_fit_failed_is_never_reported():
    """A fit that raised (`index.refine.fit.failed_at`) is not "no fit": it rejects its detection, whatever
    the floors or `min_confidence`, so that an error never widens what is reported."""
    x = detection("depth", 0.9, None)
    failed = replace(x, result=replace(x.result, fits=[failed_at(np.eye(3), np.zeros(3))]))
    assert reported(x, None, Floors(0.4, 0.2))  # not fitted at all: passes
    for at in (Floors(0.4, 0.2), Floors(0.4, 0.0), Floors(0.0)):
        assert not reported(failed, None, at)
    assert not reported(failed, 0.0, Floors(0.4, 0.2))


def test_the_other_floors_still_apply_and_min_confidence_replaces_them_all():
    assert not reported(detection("depth", 0.9, 0.5, rejected=True), None, Floors(0.4, 0.2))  # the open set
    assert not reported(detection("colour", 0.3, 0.5), None, Floors(0.4, 0.2))  # under the colour floor
    assert reported(detection("depth", 0.3, 0.1), 0.2, Floors(0.4, 0.2))
    assert not reported(detection("depth", 0.1, 0.9), 0.2, Floors(0.4, 0.2))


def test_a_colour_frame_weighed_by_its_colours_has_its_own_floor(monkeypatch):
    s = Settings(detect_floor=0.4, detect_rgb_floor=0.25, detect_depth_fit_floor=0.2)
    assert agree.COLOUR_WEIGHT == 8.0
    assert floors(s, depth=False) == Floors(0.25, 0.0, None)
    # with depth: a ceiling on the colours, the fit, a higher one for a part of a segment
    assert floors(s, depth=True) == Floors(0.4, 0.2, 0.25, 0.6)
    # an experiment without the colour check: its constant set in the process, the ceiling a setting
    monkeypatch.setattr(agree, "COLOUR_WEIGHT", 0.0)
    unweighed = s.model_copy(update={"detect_colour_ceiling": 2.0})
    assert floors(unweighed, depth=False) == Floors(0.4, 0.0, None)
    assert floors(unweighed, depth=True).colour_distance is None


def test_a_part_of_a_depth_segment_needs_more_of_it_borne_out():
    """A part of a segment larger than any registered object is a guess at where one object ends: its fit
    must explain `part_fit` of its points; a whole segment's, `depth_fit`."""
    at = Floors(0.4, 0.2, None, 0.6)
    assert reported(detection("depth", 0.9, 0.5), None, at)
    assert not reported(detection(DEPTH_PART, 0.9, 0.5), None, at)
    assert reported(detection(DEPTH_PART, 0.9, 0.7), None, at)
    assert reported(detection(DEPTH_PART, 0.9, 0.5), 0.5, at)  # min_confidence replaces the floors
    assert PART_FIT_FLOOR == 0.6 and floors(Settings(), depth=True).part_fit == 0.6
    low = Settings(detect_depth_fit_floor=0.7)
    assert floors(low, depth=True).part_fit == 0.7  # never below a whole segment's


CURVE = DetectConfidence(slope=-4.0, midpoint=0.4)


def test_a_depth_detection_s_calibrated_confidence_follows_its_fit_not_the_verifier():
    def conf(source: str, verifier: float, fit: float | None, calibrated=CURVE) -> float:
        x = detection(source, verifier, fit)
        return confidence(x.result, x.proposal, calibrated)

    assert conf("depth", 0.35, 0.4) == 0.5  # at the midpoint
    assert conf("depth", 0.35, 0.9) > 0.8 > 0.2 > conf("depth", 0.35, 0.0)  # what the depth explains decides
    assert conf("depth", 0.35, 0.9) == conf("depth", 0.45, 0.9)  # the verifier's confidence does not
    assert conf(DEPTH_PART, 0.35, 0.9) == conf("depth", 0.35, 0.9)
    assert conf("colour", 0.8, 0.9) == 0.8 * 0.9  # a colour proposal: the verifier's times the objectness's
    assert conf("depth", 0.35, None) == 0.35  # not fitted: the verifier's
    assert conf("depth", 0.35, 0.9, calibrated=None) == 0.35  # a model without the calibration
    failed = detection("depth", 0.35, 0.9)
    failed = replace(failed, result=replace(failed.result, fits=[failed_at(np.eye(3), np.zeros(3))]))
    assert confidence(failed.result, failed.proposal, CURVE) == 0.35


def test_the_detection_calibration_is_read_from_the_metadata_and_a_bad_one_is_ignored():
    assert read_detect_confidence({DETECT_KEY: json.dumps(CURVE.to_json())}) == CURVE
    assert read_detect_confidence({}) is None
    assert read_detect_confidence({DETECT_KEY: "{not json"}) is None
    assert read_detect_confidence({DETECT_KEY: json.dumps({"slope": 1.0})}) is None
