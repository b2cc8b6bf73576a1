"""What the depth leaves unexplained at the best answer's fitted pose: a frame sent with its camera, its depth
and the object's centre shows how much of the named object's surface is where the frame's depth could show
it and does not (`index.refine.depth.unexplained_of`, 0-1: points hidden by a nearer object, or over a hole
in the depth, left out).

The share is the answer's `unexplained`. Where the model's calibration has a fit term
(`service.rejection.Term`), it also enters the open-set verdict: the best answer's statistic plus the
term's weight times the share, on the term's threshold and confidence curve. An unknown object named after
the registered one whose views it resembles most has that one's distance and lead, but its surface is not
where that one's would be; a registered one half hidden by another is far from its templates, and its seen
surface still fits. A patch (no camera), a frame without depth, an object without a mesh and a detection's
verification (its own depth-fit floor and confidence judge it, `service.detection.report`) are judged as
before, on the statistic alone."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

from index.refine.depth import DepthModel, unexplained_of
from service.pipeline.answer import Result, rejudged
from service.pipeline.context import Context


@dataclass(frozen=True)
class Unexplained:
    """The best answer's unexplained share (`Result.unexplained`) and, with a fit term, its verdict and
    confidence. `models`: an object's depth model (None: it has no mesh); `setting`: the `reject_above`
    setting, as `service.rejection.judge` takes it."""

    models: Callable[[int], DepthModel | None]
    setting: float | str | None = None
    name: str = "unexplained"

    def __call__(self, result: Result, runs: list[Context] | tuple[Context, ...]) -> Result | None:
        """`result` with the share measured; None when nothing was (no change)."""
        q, d = runs[0].query, runs[0].decoded
        K = q.camera
        if K is None or q.u is None or q.estimated or d.depth is None or not result.matches:
            return None
        model = self.models(result.matches[0].object_id)
        if model is None:
            return None
        share = unexplained_of(model, *result.pose(0), K, d.depth)
        if share is None:  # none of it in view
            return None
        return rejudged(replace(result, unexplained=share), d.embedder, "fit", share, self.setting)
