"""The units check: which object sizes register, which units the hint suggests, and when units not given
are asked for."""

from pathlib import Path

import pytest

from index.geometry.units import LARGEST_MM, ORDINARY_MM, SMALLEST_MM, UNIT_SCALE, UNITS, fits, size_problem


def test_the_size_bounds():
    assert fits(SMALLEST_MM) and fits(LARGEST_MM) and fits(150.0)
    assert not fits(SMALLEST_MM * 0.99) and not fits(LARGEST_MM * 1.01)
    # taken for mm without units: no other unit of a file reads as ordinary too
    assert ORDINARY_MM[1] / ORDINARY_MM[0] <= 10


@pytest.mark.parametrize("size_mm", [60.0, 89.0, 150.0, 300.0])
@pytest.mark.parametrize("true_units", ["cm", "m", "inch"])
def test_without_units_a_file_in_others_is_refused_with_them(size_mm, true_units):
    said = size_mm / UNIT_SCALE[true_units]  # the numbers in the file
    problem = size_problem(said, None)
    assert problem is not None and "\n" not in problem
    assert f"{true_units} {size_mm:.3g} mm" in problem or f"in {true_units} it is {size_mm:.3g} mm" in problem
    assert size_problem(said * UNIT_SCALE[true_units], true_units) is None  # given, it registers


def test_given_units_are_believed_over_the_whole_range():
    assert size_problem(25.0, "mm") is None and size_problem(1500.0, "m") is None
    assert size_problem(1500.0, None) is None  # no other unit makes it ordinary
    asked = size_problem(25.0, None)  # 25 mm, or 250 mm in cm?
    assert asked is not None and "in cm 250 mm" in asked and "units=mm or units=cm" in asked


def test_a_centimetre_mesh_is_not_told_to_use_metres():
    # the issue: an 8.9 mm object in a file in cm, read as mm, was told "use units=m" (8.9 m)
    problem = size_problem(8.9, "mm")
    assert problem is not None
    assert "read in cm it is 89 mm" in problem and " m it is" not in problem
    readme = " ".join((Path(__file__).resolve().parents[3] / "README.md").read_text().split())
    assert problem in readme  # the README quotes it


def test_no_units_fit():
    problem = size_problem(1e-5, "mm")
    assert problem is not None and f"no units of {', '.join(UNITS)} make it fit" in problem
