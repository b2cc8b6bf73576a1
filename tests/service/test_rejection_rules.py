"""`service.rejection`: which threshold applies (setting, model, off), the confidence curve, the metadata."""

from __future__ import annotations

import json

import pytest

from index.store import Match
from service.rejection import REJECT_KEY, Calibration, Term, judge, read_calibrations, termed


def match(distance: float) -> Match:
    return Match(1, "a", 0.0, 0.0, 0.0, distance)


CAL = Calibration("local", threshold=1.0, slope=10.0, midpoint=0.9)


def test_the_model_threshold_rejects_above_it_only():
    assert judge([match(0.99), match(2.0)], "local", CAL).reason is None
    reason = judge([match(1.01)], "local", CAL).reason
    assert reason is not None and "local distance 1.01 is above 1" in reason and "val frames" in reason


def test_the_setting_replaces_the_model_threshold_and_off_turns_it_off():
    assert judge([match(0.5)], "local", CAL, setting=0.4).reason is not None
    assert judge([match(1.5)], "local", CAL, setting=2.0).reason is None
    assert judge([match(99.0)], "local", CAL, setting="off").reason is None
    assert judge([match(99.0)], "descriptor", None).reason is None  # no calibration, no setting


def test_no_registered_object_is_a_reason_too():
    assert judge([], "descriptor", None).reason == "no object is registered"


def test_confidence_falls_with_the_distance_and_is_half_at_the_midpoint():
    c = judge([match(0.5), match(0.9), match(1.3)], "local", CAL).confidences
    assert c[1] == pytest.approx(0.5)
    assert c[0] > 0.95 and c[2] < 0.05
    assert CAL.confidence(1e6) < 1e-300 and CAL.confidence(-1e6) == 1.0  # no overflow


def test_metadata_round_trip_and_a_bad_one_is_ignored():
    meta = {REJECT_KEY: json.dumps({"local": CAL.to_json(), "other": {"threshold": 1}})}
    assert read_calibrations(meta) == {"local": CAL}
    assert read_calibrations({REJECT_KEY: "{not json"}) == {}
    assert read_calibrations({REJECT_KEY: json.dumps({"local": {"slope": 1}})}) == {}
    assert read_calibrations({}) == {}


def test_an_older_calibration_thresholds_the_distance_and_records_no_settings():
    old = {"local": {"threshold": 1.0, "slope": 10.0, "midpoint": 0.9, "frames": "val", "rerank": 200}}
    cal = read_calibrations({REJECT_KEY: json.dumps(old)})["local"]
    assert cal.statistic == "distance" and cal.weight == 0.0 and cal.settings is None
    assert cal.values([match(0.7), match(0.8)]) == [0.7, 0.8]


def other(distance: float, object_id: int = 2) -> Match:
    return Match(object_id, "b", 0.0, 0.0, 0.0, distance)


LEAD = Calibration("local", threshold=0.3, slope=10.0, midpoint=0.2, statistic="lead", weight=1.0)


def test_lead_is_the_distance_less_the_lead_over_the_nearest_other_object():
    values = LEAD.values([match(0.5), match(0.6), other(0.9)])
    assert values == pytest.approx([0.5 - 0.4, 0.6 - 0.3, 0.9])  # the other object's lead is none
    # one object listed: its lead is at least the last answer's distance
    assert LEAD.values([match(0.5), match(0.7)]) == pytest.approx([0.3, 0.7])


def test_lead_rejects_a_near_answer_that_another_object_answers_about_as_well():
    assert judge([match(0.5), other(0.9)], "local", LEAD).reason is None  # 0.1: far ahead
    reason = judge([match(0.5), other(0.55)], "local", LEAD).reason  # 0.45: a toss-up
    assert reason is not None and "lead over the nearest other object 0.45 is above 0.3" in reason
    meta = {REJECT_KEY: json.dumps({"local": LEAD.to_json()})}
    assert read_calibrations(meta) == {"local": LEAD}
    bad = {REJECT_KEY: json.dumps({"local": {**LEAD.to_json(), "statistic": "vibes"}})}
    assert read_calibrations(bad) == {}


COLOURED = Calibration(
    "local", threshold=0.3, slope=10.0, midpoint=0.2, statistic="lead", weight=1.0,
    colour=Term(weight=1.0, threshold=0.5, slope=8.0, midpoint=0.4),
)  # fmt: skip


def test_the_colour_term_adds_the_colour_distance_and_judges_on_its_own_threshold():
    verdict = judge([match(0.5), other(0.9)], "local", COLOURED)
    assert verdict.reason is None and verdict.value == pytest.approx(
        0.1
    )  # the statistic alone: judged as before
    # its colours are its object's: 0.1 + 0.2 stands under the term's 0.5 ...
    confidence, reason = termed(0.1, "colour", 0.2, "local", COLOURED)
    assert reason is None and confidence == pytest.approx(COLOURED.colour.confidence(0.3))  # type: ignore[union-attr]
    # ... another object's colours where its pose puts it: 0.1 + 0.6 is above, though the statistic was not
    confidence, reason = termed(0.1, "colour", 0.6, "local", COLOURED)
    assert reason is not None and "plus 1 x its colour distance 0.7 is above 0.5" in reason
    assert confidence < 0.5
    assert termed(0.1, "colour", 0.6, "local", COLOURED, setting="off")[1] is None  # the setting still rules
    assert termed(0.1, "colour", 0.6, "local", COLOURED, setting=1.0)[1] is None


def test_a_colour_term_round_trips_through_the_metadata_and_a_bad_one_is_ignored():
    meta = {REJECT_KEY: json.dumps({"local": COLOURED.to_json()})}
    assert read_calibrations(meta) == {"local": COLOURED}
    assert read_calibrations({REJECT_KEY: json.dumps({"local": LEAD.to_json()})})["local"].colour is None
    bad = {REJECT_KEY: json.dumps({"local": {**LEAD.to_json(), "colour": {"weight": 1.0}}})}
    assert read_calibrations(bad) == {}


FITTED = Calibration(
    "descriptor", threshold=0.3, slope=10.0, midpoint=0.2, statistic="lead", weight=0.5,
    fit=Term(weight=0.2, threshold=0.4, slope=9.0, midpoint=0.35),
)  # fmt: skip


def test_the_fit_term_adds_the_unexplained_share_and_round_trips():
    # half its surface unexplained: 0.25 + 0.2 x 0.5 = 0.35 stands under the term's 0.4 ...
    confidence, reason = termed(0.25, "fit", 0.5, "descriptor", FITTED)
    assert reason is None and confidence == pytest.approx(FITTED.fit.confidence(0.35))  # type: ignore[union-attr]
    # ... all of it unexplained: 0.45 is above, though the statistic alone (0.25 < 0.3) was not
    confidence, reason = termed(0.25, "fit", 1.0, "descriptor", FITTED)
    assert reason is not None and "plus 0.2 x the share of it the depth leaves unexplained 0.45" in reason
    meta = {REJECT_KEY: json.dumps({"descriptor": FITTED.to_json()})}
    assert read_calibrations(meta) == {"descriptor": FITTED}
    assert FITTED.colour is None and FITTED.with_term("colour", FITTED.fit).colour == FITTED.fit
