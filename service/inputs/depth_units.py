"""Is the depth in millimetres? A depth image in other units (0.1 mm, as some BOP datasets store it, or
cm) sent without the right `depth_scale` would otherwise be cut at a distance 10x off and answered with a
confident wrong object. Geometry alone cannot tell: scaling every depth scales the scene and its picture
stays the same. What can: the scene's depth against what a depth camera measures, and the model's metric
window (its `window_mm`, 200 mm for the shipped models) against the frame: at the distance the depth says,
the window must cover enough pixels to be recognised (at 10x too far it shrinks to a few pixels), and no
object the size of the window is nearer than the window is wide (at 10x too near it would be).

Each check refuses a query (422) naming what looks wrong and the `depth_scale` that would make the depth
plausible: the sent scale times the smallest power of ten that passes the same check; or, when that
scale says the values are whole metres (or decimetres), to store millimetres instead. A user whose
object really is that near or far can say so with `distance_mm`.

Each object has the window its size asks for (`index.templates.windows`), and a frame query is cut once per window
class among the registered objects: the checks run per class with its window (a 50 mm part's window may
be 150 mm away, a 1.6 m one's not nearer than 1.6 m). A class the depth makes implausible is left out of
that query; only when every class is, the query is refused, with the reason of the class nearest the
model's window (`service.pipeline.Pipeline`). So with objects of very different sizes registered, depth 10
times off may be plausible for one class and go on against its objects: the answer's `distance_mm` then
shows the distance read."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from service.errors import ApiError, NothingMeasured

#: Beyond this no depth camera of the kind the service is for measures (a Kinect: ~0.5 to 4.5 m).
FARTHEST_MM = 10_000.0
#: Powers of ten a suggestion may correct the scale by, nearest first.
DECADES = (-1, 1, -2, 2, -3, 3)
UNITS = {0.1: "0.1 mm", 1.0: "mm", 10.0: "cm", 1000.0: "m"}
#: A scale from this many mm per unit up means the 16-bit values are whole decimetres or metres: such
#: depth holds nothing of an object's shape (a 200 mm window spans 0 or 1 step of it), so the answer is
#: to store millimetres, not to send the scale.
COARSE_SCALE = 100.0
#: How depth in metres becomes the 16-bit PNG of millimetres the service reads.
METRES_TO_MM = "cv2.imwrite('depth.png', np.round(np.nan_to_num(d_m) * 1000).astype(np.uint16))"


def check_frame_distance(
    distance_mm: float, focal_px: float, window_mm: float, size_px: int, depth_scale: float
) -> None:
    """The distance measured at a frame's centre (mm): within a depth camera's range, not nearer than the
    model's window is wide, and far enough for the window to span at least half the model's input."""

    def problem(d: float) -> str | None:
        if d > FARTHEST_MM:
            return f"farther than a depth camera measures ({FARTHEST_MM / 1000:g} m)"
        if d < window_mm:
            return f"nearer than the model's {window_mm:g} mm window is wide"
        px = focal_px * window_mm / d
        if px < size_px / 2:
            return f"where the model's {window_mm:g} mm window spans {px:.0f} px of the frame (it takes {size_px})"
        return None

    _check(distance_mm, depth_scale, problem)


def check_scene_depth(
    depth_mm: np.ndarray, focal_px: float, windows_mm: Sequence[float], size_px: int, depth_scale: float
) -> None:
    """A whole frame's depth (mm), sent to find the objects in it: the near part of the scene (the tenth of
    its measured pixels nearest the camera, where objects stand before a table or wall: a far wall filling
    most of the frame moves it little) must lie at a distance at which some registered object's window
    (`windows_mm`, the model's first) can be seen, as `check_frame_distance` asks of a frame's centre. Depth
    in other units than `depth_scale` says would otherwise find nothing and answer 200 "nothing found"."""
    valid = depth_mm[::4, ::4]
    valid = valid[valid > 0]
    if not valid.size:
        raise ApiError(
            422, "the depth image measures nothing (every value is 0): is it the depth of this frame?"
        )
    near = float(np.percentile(valid, 10))
    refusals = []
    for window in windows_mm:
        try:
            check_frame_distance(near, focal_px, window, size_px, depth_scale)
            return
        except ApiError as e:
            refusals.append(e)
    first = refusals[0]
    said = first.detail.replace("the depth at the centre says", "the near tenth of the frame's depth says")
    raise ApiError(422, said.replace("; if the object really is there, send distance_mm", ""))


def check_patch_distance(distance_mm: float, window_mm: float, depth_scale: float) -> None:
    """The distance at a patch's centre (mm): a patch spans the window whatever its distance, so only the
    range is checked."""

    def problem(d: float) -> str | None:
        if d > FARTHEST_MM:
            return f"farther than a depth camera measures ({FARTHEST_MM / 1000:g} m)"
        if d < window_mm:
            return f"nearer than the model's {window_mm:g} mm window is wide"
        return None

    _check(distance_mm, depth_scale, problem)


def check_given_distance(
    surface_mm: np.ndarray, distance_mm: float, window_mm: float, depth_scale: float
) -> None:
    """Depth against a given `distance_mm`: the model reads depth within half a window of the surface
    near the distance, so a patch whose centre holds none there is blank to it. Refused when, besides,
    the depth there is about a power of ten off the distance (within a factor 10^0.25); otherwise (an
    occluder, a hole) it goes on as before. `surface_mm`: the valid depths (mm, along the rays) of the
    window's central quarter."""
    if not surface_mm.size or (np.abs(surface_mm - distance_mm) < window_mm / 2).any():
        return
    median = float(np.median(surface_mm))
    decades = np.log10(distance_mm / median)  # how many powers of ten the depth is off by
    k = int(np.round(decades))
    if k in DECADES and abs(decades - k) < 0.25:
        what = f"distance_mm is {distance_mm:g} but the depth around it says {median:.0f} mm (at depth_scale={depth_scale:g})"
        raise ApiError(422, _message(what, depth_scale, k, given=True))


def _check(distance_mm: float, depth_scale: float, problem: Callable[[float], str | None]) -> None:
    why = problem(distance_mm)
    if why is None:
        return
    k = next((k for k in DECADES if problem(distance_mm * 10.0**k) is None), None)
    what = f"the depth at the centre says {distance_mm:.0f} mm (at depth_scale={depth_scale:g}), {why}"
    raise NothingMeasured(_message(what, depth_scale, k))


def suggested_scale(depth_scale: float, k: int) -> float:
    """The sent scale corrected by 10^k, rounded to what a person would type."""
    return float(f"{depth_scale * 10.0**k:.6g}")


def _message(what: str, depth_scale: float, k: int | None, given: bool = False) -> str:
    if k is None:
        return f"{what}: is depth_scale (mm per unit) right?"
    scale = suggested_scale(depth_scale, k)
    units = UNITS.get(scale, f"{scale:g} mm")
    escape = "" if given else "; if the object really is there, send distance_mm"
    if scale >= COARSE_SCALE:
        return (
            f"{what}: depth looks like whole {'metres' if scale == 1000.0 else units}, which keep nothing of "
            f"an object's shape in 16-bit integers: store depth as millimetres in a 16-bit PNG (from depth "
            f"in metres d_m: {METRES_TO_MM}); if the values are integers of a finer unit, send depth_scale "
            f"(mm per unit){escape}"
        )
    return f"{what}: depth looks like {units} units: send depth_scale={scale:g}{escape}"
