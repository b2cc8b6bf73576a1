"""A mesh file's units: the scales accepted, and whether the object they make is a size a patch can show.

A mesh file says nothing of its units. Read in the wrong ones, an object comes out 10, 25.4 or 1000 times
too small or too large, and its templates show a speck, nothing at all (black), or the inside of the
object. `index.mesh.load_mesh(window_mm=...)` refuses such an object for `POST /objects`,
`posedesc build-index` and `posedesc render`, and says which units would make its size fit.
"""

from __future__ import annotations

from typing import Literal, get_args

Units = Literal["mm", "cm", "m", "inch"]  # the API's and the CLI's choices
UNITS: tuple[str, ...] = get_args(Units)
# millimetres per unit of the file
UNIT_SCALE = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "inch": 25.4}
assert tuple(UNIT_SCALE) == UNITS

# An object fits a patch window of w mm when its diameter is between w / 5 (13 px of a 64 px patch: less
# shows too little to tell objects apart) and 2 w (from LineMOD's 400 mm the camera is then within 200 mm of
# its surface, and a patch shows a quarter of it). For the 200 mm window that is 40-400 mm (LineMOD's objects
# are 100-300 mm), a span of 10: a file read in units 10 or more times off never fits.
SMALLEST, LARGEST = 1 / 5, 2.0


def fits(diameter_mm: float, window_mm: float) -> bool:
    return window_mm * SMALLEST <= diameter_mm <= window_mm * LARGEST


def size_problem(diameter_mm: float, units: str, window_mm: float) -> str | None:
    """Why an object `diameter_mm` across, read from a file in `units`, does not fit the window, and
    which units would make it fit (metric first), in one line; None when it fits."""
    if fits(diameter_mm, window_mm):
        return None
    lo, hi = window_mm * SMALLEST, window_mm * LARGEST
    size = "too small" if diameter_mm < lo else "too large"
    said = diameter_mm / UNIT_SCALE[units]  # the file's own numbers
    better = [(u, said * s) for u, s in UNIT_SCALE.items() if u != units and fits(said * s, window_mm)]
    if better:
        hint = (
            "read in " + ", in ".join(f"{u} it is {_mm(mm)}" for u, mm in better) + ": give the file's units"
        )
    else:
        hint = f"no units of {', '.join(UNITS)} make it fit: check the file"
    return (
        f"the object is {_mm(diameter_mm)} across read in {units}: {size} for the {window_mm:g} mm patch "
        f"window ({lo:g}-{hi:g} mm fit); {hint}"
    )


def _mm(x: float) -> str:
    return f"{x:,.0f} mm" if x >= 1000 else f"{x:.3g} mm"
