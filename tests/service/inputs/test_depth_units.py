"""The depth-units checks on their own (`service.inputs.depth_units`): which distances are refused, and the scale
each refusal suggests. The real Kinect frame sent in the wrong units is in test_real_depth.py."""

from __future__ import annotations

import numpy as np
import pytest

from service.errors import ApiError
from service.inputs.depth_units import check_frame_distance, check_given_distance, check_patch_distance

F, WINDOW, SIZE = 572.0, 200.0, 64  # a Kinect's focal length, the shipped models' window and input


def refusal(check, *args) -> str:
    with pytest.raises(ApiError) as e:
        check(*args)
    assert e.value.status_code == 422
    return e.value.detail


@pytest.mark.parametrize("distance", [350.0, 600.0, 1200.0, 3000.0])
def test_a_kinects_range_passes(distance):
    check_frame_distance(distance, F, WINDOW, SIZE, 1.0)
    check_patch_distance(distance, WINDOW, 1.0)


@pytest.mark.parametrize(
    ("distance", "sent", "suggested", "why"),
    [
        (11_000.0, 1.0, "depth_scale=0.1", "farther than a depth camera"),
        (6_000.0, 1.0, "depth_scale=0.1", "spans 19 px"),  # 0.6 m in 0.1 mm: in range, but 19 px
        (95.0, 1.0, "depth_scale=10", "nearer than the model's 200 mm window"),  # cm
        (60_000.0, 1.0, "depth_scale=0.01", "farther"),  # 0.6 m in 0.01 mm: 0.1 is not enough
        (9_000.0, 10.0, "depth_scale=1", "spans"),  # mm sent as cm
    ],
)
def test_a_frame_in_other_units_is_refused_with_the_scale_that_fits(distance, sent, suggested, why):
    detail = refusal(check_frame_distance, distance, F, WINDOW, SIZE, sent)
    assert detail.endswith(f"{suggested}; if the object really is there, send distance_mm"), detail
    assert why in detail and f"{distance:.0f} mm" in detail


def test_the_window_must_span_half_the_input():
    """Far objects refused by the size they come out at, which depends on the focal length."""
    check_frame_distance(3_500.0, F, WINDOW, SIZE, 1.0)  # 33 px
    assert "spans 29 px" in refusal(check_frame_distance, 4_000.0, F, WINDOW, SIZE, 1.0)
    check_frame_distance(4_000.0, 2 * F, WINDOW, SIZE, 1.0)  # a longer lens: 57 px


def test_a_patch_is_checked_for_range_only():
    check_patch_distance(6_000.0, WINDOW, 1.0)  # a patch spans the window at any distance
    assert "depth_scale=10" in refusal(check_patch_distance, 95.0, WINDOW, 1.0)
    assert "depth_scale=0.1" in refusal(check_patch_distance, 12_000.0, WINDOW, 1.0)


def test_a_given_distance_is_checked_against_the_depth_around_it():
    rng = np.random.default_rng(0)
    surface = 560.0 + 40.0 * rng.random(200)  # an object's face 0-40 mm before its origin at 600
    check_given_distance(surface, 600.0, WINDOW, 1.0)
    detail = refusal(check_given_distance, surface * 10, 600.0, WINDOW, 1.0)
    assert "distance_mm is 600" in detail and detail.endswith("send depth_scale=0.1"), detail
    assert "depth_scale=10" in refusal(check_given_distance, surface / 10, 600.0, WINDOW, 1.0)


@pytest.mark.parametrize("surface", [np.full(50, 300.0), np.full(50, 2500.0), np.zeros(0)])
def test_depth_that_is_no_power_of_ten_off_goes_on(surface):
    """An occluder in front, the background through a hole, or no depth: not a units mistake."""
    check_given_distance(surface, 600.0, WINDOW, 1.0)


def test_depth_in_whole_metres_is_told_to_store_millimetres():
    """A 16-bit PNG of metres holds 0, 1 or 2 at a Kinect's range: no depth_scale makes it useful."""
    for detail in (
        refusal(check_frame_distance, 1.0, F, WINDOW, SIZE, 1.0),  # 1 m stored as 1
        refusal(check_patch_distance, 1.0, WINDOW, 1.0),
        refusal(check_given_distance, np.full(20, 0.6), 600.0, WINDOW, 1.0),
    ):
        assert "depth_scale=1000" not in detail and "looks like whole metres" in detail, detail
        assert "store depth as millimetres in a 16-bit PNG" in detail and "np.uint16" in detail
        assert "if the values are integers of a finer unit, send depth_scale (mm per unit)" in detail
    # integers of a finer unit (cm) still get the scale that turns them into mm
    assert "depth looks like cm units: send depth_scale=10;" in refusal(
        check_frame_distance, 60.0, F, WINDOW, SIZE, 1.0
    )
