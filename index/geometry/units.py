"""A mesh file's units: the scales accepted, the sizes of object registered, and when a file's units are
doubtful.

A mesh file says nothing of its units. Read in the wrong ones, an object comes out 10, 25.4 or 1000 times
too small or too large: its templates would show another object's size, and a query would be answered
with it. Each object gets the patch window its size asks for (`index.templates.windows`), so any object from
`SMALLEST_MM` to `LARGEST_MM` across registers. `index.templates.mesh.load_mesh(check_size=True)` refuses one outside
that for `POST /objects`, `posedesc build-index` and `posedesc render`, and says which units would make its
size fit.

A range of 100 no longer tells mm from cm by size alone (a 25 mm part and a 250 mm one in cm read alike),
so wrong units are caught where they still can be, by this rule: units given are believed over the whole
range; units not given are taken as mm (CAD and BOP files are), except that an object whose size in mm is
unusual (outside `ORDINARY_MM`, the sizes of the household and industrial objects the service was first
made for: LineMOD's are 100-300 mm) while another unit would make it ordinary is refused, naming both
readings, until the units are given. So a 30 cm object in a cm file sent without units is asked about (30
mm or 300 mm?), where it would otherwise register as a 30 mm part; and a 1.5 m object in mm registers as it
is, since no other unit makes it ordinary. Every registration's answer says the size it read
(`diameter_mm`) and the window chosen (`window_mm`).
"""

from __future__ import annotations

from typing import Literal, get_args

Units = Literal["mm", "cm", "m", "inch"]  # the API's and the CLI's choices
UNITS: tuple[str, ...] = get_args(Units)
# millimetres per unit of the file
UNIT_SCALE = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "inch": 25.4}
assert tuple(UNIT_SCALE) == UNITS

# The objects registered: from 20 mm (a patch window of 35 mm, `index.templates.windows`; a smaller part spans too few
# pixels of a frame to be told apart at any distance a depth camera measures) to 2 m (a window of 2.3 m).
SMALLEST_MM, LARGEST_MM = 20.0, 2000.0
# The sizes taken for mm without question when no units are given: the 200 mm window's old range (1/5 to 2
# windows), a span of 10, so that no other unit of a file (10, 25.4 or 1000 times off) is ordinary too.
ORDINARY_MM = (40.0, 400.0)


def fits(diameter_mm: float) -> bool:
    return SMALLEST_MM <= diameter_mm <= LARGEST_MM


def _ordinary(diameter_mm: float) -> bool:
    return ORDINARY_MM[0] <= diameter_mm <= ORDINARY_MM[1]


def size_problem(diameter_mm: float, units: str | None) -> str | None:
    """Why an object `diameter_mm` across, read from a file in `units` (None: not given, read as mm), is
    refused, and which units would make it fit (metric first), in one line; None when it is accepted."""
    read = units or "mm"
    said = diameter_mm / UNIT_SCALE[read]  # the file's own numbers
    if not fits(diameter_mm):
        size = "too small" if diameter_mm < SMALLEST_MM else "too large"
        better = [(u, said * s) for u, s in UNIT_SCALE.items() if u != read and fits(said * s)]
        if better:
            hint = "read in " + ", in ".join(f"{u} it is {_mm(mm)}" for u, mm in better)
            hint += ": give the file's units"
        else:
            hint = f"no units of {', '.join(UNITS)} make it fit: check the file"
        return (
            f"the object is {_mm(diameter_mm)} across read in {read}: {size} "
            f"({SMALLEST_MM:g}-{LARGEST_MM:,.0f} mm register); {hint}"
        )
    if units is not None or _ordinary(diameter_mm):
        return None
    others = [(u, said * s) for u, s in UNIT_SCALE.items() if u != "mm" and _ordinary(said * s)]
    if not others:
        return None
    readings = ", in ".join(f"{u} {_mm(mm)}" for u, mm in others)
    choices = " or ".join(f"units={u}" for u in ("mm", *(u for u, _ in others)))
    return (
        f"the file's units are not given: read in mm the object is {_mm(diameter_mm)} across, in {readings}; "
        f"say which ({choices})"
    )


def _mm(x: float) -> str:
    return f"{x:,.0f} mm" if x >= 1000 else f"{x:.3g} mm"
