"""The units check: which objects fit the patch window, and which units the hint suggests."""

from pathlib import Path

import pytest

from index.units import LARGEST, SMALLEST, UNIT_SCALE, UNITS, fits, size_problem


def test_the_window_bounds():
    assert fits(150, 200) and fits(200 * SMALLEST, 200) and fits(200 * LARGEST, 200)
    assert not fits(200 * SMALLEST * 0.99, 200) and not fits(200 * LARGEST * 1.01, 200)
    # a file read in units 10 times off never fits: cm as mm, mm as cm
    assert LARGEST / SMALLEST <= 10


@pytest.mark.parametrize("size_mm", [60.0, 89.0, 150.0, 300.0])
@pytest.mark.parametrize("true_units", ["cm", "m", "inch"])
def test_the_hint_suggests_units_that_fit_and_the_true_ones(size_mm, true_units):
    said = size_mm / UNIT_SCALE[true_units]  # the numbers in the file
    problem = size_problem(said, "mm", 200.0)
    if fits(said, 200.0):  # e.g. 300 mm in inch is 11.8 "mm": possible, not refused
        assert problem is None
        return
    assert problem is not None and "\n" not in problem
    suggested = [u for u in UNITS if f" {u} it is " in problem]
    assert true_units in suggested
    assert all(fits(said * UNIT_SCALE[u], 200.0) for u in suggested)
    assert f"in {true_units} it is {size_mm:.3g} mm" in problem


def test_a_centimetre_mesh_is_not_told_to_use_metres():
    # the issue: an 89 mm object in a file in cm, read as mm, was told "use units=m" (8.9 m)
    problem = size_problem(8.9, "mm", 200.0)
    assert problem is not None
    assert "read in cm it is 89 mm" in problem and " m it is" not in problem
    readme = " ".join((Path(__file__).resolve().parents[2] / "README.md").read_text().split())
    assert problem in readme  # the README quotes it


def test_no_units_fit():
    problem = size_problem(1e-5, "mm", 200.0)
    assert problem is not None and "no units of mm, cm, m, inch make it fit" in problem
