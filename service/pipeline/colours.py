"""The colours at the best answer's pose, after the pose fit: a colour frame sent with its camera and the
object's centre shows whether the frame's colours there are the named object's
(`index.refine.chroma.chroma_distance`, 0-2; the detection's colour check measures the same,
`service.detection.agree`).

The distance is the answer's `colour_distance`. Where the model's calibration has a colour term
(`service.rejection.Term`) and the frame has no depth, it also enters the open-set verdict: the best
answer's statistic plus the term's weight times the distance, on the term's threshold and confidence
curve. An object not registered is named after the registered one whose views it resembles most, with that
one's distance and lead, but not with its colours. A patch (no camera; its colours tell the parts of a mixed
store apart: `patch_colour_distance`), a shape-only object (no colours to check) and a detection's
verification (its own colour check weighs it, `service.detection.agree`) are judged as before, on the
statistic alone."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2

from index.features.patches import patch_camera
from index.refine.chroma import SurfaceColours, chroma_distance
from service.pipeline.answer import Result, rejudged
from service.pipeline.context import Context, Decoded


@dataclass(frozen=True)
class Colours:
    """The best answer's colour distance (`Result.colour_distance`) and, with a colour term, its verdict
    and confidence. `surfaces`: an object's surface colours (None: it has none); `setting`: the
    `reject_above` setting, as `service.rejection.judge` takes it."""

    surfaces: Callable[[int], SurfaceColours | None]
    setting: float | str | None = None
    name: str = "colours"

    def __call__(self, result: Result, runs: list[Context] | tuple[Context, ...]) -> Result | None:
        """`result` with the colours measured; None when nothing was (no change)."""
        q, d = runs[0].query, runs[0].decoded
        K = q.camera
        if (
            K is None
            or q.u is None
            or q.estimated
            or d.rgb is None
            or d.modality == "depth"
            or not result.matches
        ):
            return None
        surface = self.surfaces(result.matches[0].object_id)
        if surface is None:
            return None
        distance = chroma_distance(d.rgb, K, surface, *result.pose(0))
        if distance is None:  # too little of it in view to say
            return None
        measured = replace(result, colour_distance=distance)
        if d.depth is not None:  # a frame with depth: judged by what the depth shows (`unexplained`)
            return measured
        return rejudged(measured, d.embedder, "colour", distance, self.setting)


def patch_colour_distance(
    surfaces: Callable[[int], SurfaceColours | None], d: Decoded, window_mm: float, result: Result
) -> float | None:
    """How far a patch's colours (no camera) are from the best answer's object's where its pose shows it
    (`chroma_distance`, 0-2), in the virtual camera of the patch as the network saw it (`patch_camera`: the
    patch at the model's size spanning `window_mm` at the distance it was answered at); None without colour,
    an object without colours, or too little of it in view. At the answer's pose: fitted in the same camera
    when the patch has depth (`service.pipeline.fit.fitted_camera`). What tells the parts of a mixed store
    apart for a patch
    (`service.recognition.best_patch_part`)."""
    if d.rgb is None or not result.matches:
        return None
    surface = surfaces(result.matches[0].object_id)
    if surface is None:
        return None
    spec = replace(d.embedder.info.spec, window_mm=window_mm)
    rgb = cv2.resize(d.rgb, (spec.size, spec.size), interpolation=cv2.INTER_AREA)  # as the cut resizes it
    return chroma_distance(rgb, patch_camera(spec, result.distance_mm), surface, *result.pose(0))
