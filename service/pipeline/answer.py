"""The answers' assembly: the k distinct answers in the order the stages left them (`ranked_matches`), the
open-set verdict on the best (`service.rejection`), and where each answer puts the object's origin along
the ray (`origin_distances`): the distance its `t` is at.

`distance_mm`, sent or not, means one thing: from the camera to the object's origin along the ray through
the centre (‖t‖). Sent, it is the answer's distance. Measured from depth, it is the surface at the centre
(the median of the central quarter of the patch, as the templates measure theirs), and each answer adds its
own template's offset (origin minus surface for that object from that viewpoint, `index.templates.surface`): the
surface of a mug seen from the side lies its radius in front of its origin, seen from above its half height.

A query cut through several windows (one per window class of the store's objects: `service.pipeline`)
runs the stages once per class; the answers are each class's ranked answers merged by their distance
(every class is scored the same way), each answer's origin measured in its own class's window."""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from index.features.embed import Embedder
from index.features.patches import surface_depth
from index.refine.fit import Fit
from index.store import Match, Snapshot
from index.templates.surface import offset_of
from service.pipeline.context import Context
from service.pipeline.query import untextured
from service.poses import match_pose
from service.rejection import LISTED, judge, read_calibrations, reason_of, served_score, termed
from service.settings import Settings


@dataclass
class Result:
    """The answers, and where they are: `ray` (3,) the unit ray through the object's centre in the query's
    camera (the patch camera for a patch: the optical axis), `distance_mm` how far along it the query was
    cut. With a match's view they give its pose (`service.poses`). `score`: what each match's distance
    is ("local" when re-ranked, else "descriptor"); `confidences` per match and `reason` (the best answer
    rejected, or None) from `service.rejection`. `timings_ms`: `service.pipeline`'s docstring."""

    model: str
    matches: list[Match]
    timings_ms: dict[str, float]
    ray: np.ndarray
    distance_mm: float
    score: str = "descriptor"
    confidences: list[float | None] = field(default_factory=list)
    reason: str | None = None
    #: per match, how far its object's origin lies along `ray` (mm): `distance_mm` when it was sent, else
    #: the measured surface plus the match's template offset (`origin_distances`)
    origins_mm: list[float] = field(default_factory=list)
    #: the best matches' pose fits (`service.pipeline.fit`), as many as were fitted (None: not fitted)
    fits: list[Fit | None] = field(default_factory=list)
    #: the best answer's open-set statistic (`service.rejection.Verdict.value`; None without answers)
    statistic: float | None = None
    #: per match, its open-set statistic (`service.rejection.Verdict.values`), which moves with it when the
    #: depth re-orders the answers: the verdict is then the new best's (`shown`)
    statistics: list[float] = field(default_factory=list)
    #: how far the frame's colours at the best answer's pose are from its object's, 0-2
    #: (`service.pipeline.colours`; None: not measured)
    colour_distance: float | None = None
    #: the share of the best answer's surface the frame's depth leaves unexplained at its fitted pose, 0-1
    #: (`service.pipeline.unexplained`; None: not measured)
    unexplained: float | None = None

    def fitted(self, i: int) -> Fit | None:
        """Match i's fit when the fit moved it, else None (its pose is its template's)."""
        fit = self.fits[i] if i < len(self.fits) else None
        return fit if fit is not None and fit.moved else None

    def pose(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Match i's pose (R_m2c (3, 3), t_m2c (3,) mm) in the query's camera: its fit's when the fit moved
        it, else its template's along the ray at its origin's distance (`service.poses.match_pose`)."""
        fit = self.fitted(i)
        if fit is not None:
            return fit.R, fit.t
        return match_pose(self.matches[i], self.ray, self.origins_mm[i])


def ranked_matches(ctx: Context) -> list[Match]:
    """The query's answers (`Context.wanted` of them: k, or what the verdict reads): the search's matches, or once re-ranked those scored in the order of their
    scores (two refined to one viewpoint: the better one stays), each at the pose it was scored at, then
    those without local features in the search's order."""
    k, matches, r = ctx.wanted, ctx.matches, ctx.ranked
    if r is None:
        return list(matches[:k])
    order, seen = np.argsort(r.scores, kind="stable"), set()
    out: list[Match] = []
    for j in order:
        if len(out) >= k:
            break
        if r.keys[j] in seen:
            continue
        seen.add(r.keys[j])
        m = replace(matches[r.have[j]], distance=float(r.scores[j]))
        if (r.keys[j], r.rolls[j]) != r.first[j]:  # the sweep or refinement moved it
            m = replace(m, azimuth=r.keys[j][1], elevation=r.keys[j][2], inplane=r.rolls[j])
        out.append(m)
    scored = set(r.have)  # then those without local features, read only as far as k needs
    rest = (matches[i] for i in range(len(matches)) if i not in scored)
    return out + list(itertools.islice(rest, max(k - len(out), 0)))


def handicapped(m: Match, snapshot: Snapshot, handicap: float) -> Match:
    """`m` with its distance times 1 + `handicap` when its object is shape-only (`untextured`): in
    colour, a grey render is near any patch (`Settings.shape_handicap`)."""
    rec = snapshot.objects.get(m.object_id)
    if rec is None or not untextured(rec):
        return m
    return replace(m, distance=m.distance * (1.0 + handicap))


def answer(runs: Sequence[Context], timings_ms: dict[str, float], settings: Settings) -> Result:
    """The response to a query run once per window class (`runs`, at least one): the first k of their
    answers (`ranked_matches`; merged by distance when several) with the verdict, read on all of them
    (`Context.wanted`), and their origins."""
    ctx, d, p = runs[0], runs[0].decoded, runs[0].patches
    assert p is not None  # `Cut` ran
    found = [(m, i) for i, run in enumerate(runs) for m in ranked_matches(run)]
    if settings.shape_handicap > 0 and d.modality != "depth":
        found = [(handicapped(m, runs[i].snapshot, settings.shape_handicap), i) for m, i in found]
        found = sorted(found, key=lambda f: f[0].distance)  # stable: ties keep their order
    if len(runs) > 1:
        found = sorted(found, key=lambda f: f[0].distance)[: ctx.wanted]
    matches = [m for m, _ in found]
    calibration = read_calibrations(d.embedder.info.extra, d.embedder.path.name).get(ctx.score)
    verdict = judge(matches, ctx.score, calibration, settings.reject_above)
    kept = found[: ctx.query.k]
    origin = {}
    for i, run in enumerate(runs):
        mine = [m for m, j in kept if j == i]
        origin[i] = iter(_origins(run, mine))
    origins = [next(origin[i]) for _, i in kept]
    matches = [m for m, _ in kept]
    return Result(
        d.embedder.path.stem,
        matches,
        timings_ms,
        p.ray,
        p.distance,
        ctx.score,
        verdict.confidences[: ctx.query.k],
        verdict.reason,
        origins,
        statistic=verdict.value,
        statistics=verdict.values[: ctx.query.k],
    )


def shown(result: Result, embedder: Embedder, setting: float | str | None) -> Result:
    """`result` judged on the answer it now shows first: after the depth's re-ordering (`service.pipeline.fit`)
    the best answer may be another than the nearest, and the verdict is its own, on its own statistic (as
    every answer's, its distance less the lead it has over the nearest answer of another object), which is
    what the calibration measures on the answers as the service lists them (`evaluation.openset`). Before,
    the verdict stayed the nearest answer's whatever was shown first. `setting`: `reject_above`."""
    if not result.statistics or result.statistic == result.statistics[0]:
        return result
    calibration = read_calibrations(embedder.info.extra, embedder.path.name).get(result.score)
    value = result.statistics[0]
    return replace(result, statistic=value, reason=reason_of(value, result.score, calibration, setting))


def rejudged(
    result: Result, embedder: Embedder, measure: str, measured: float, setting: float | str | None
) -> Result:
    """`result` with its best answer judged again once the frame shows `measure` of it ("colour", its colour
    distance; "fit", the share of it the depth leaves unexplained: `service.rejection.termed`), where the
    model's calibration of its score has that term; else as it was. `setting`: `reject_above`."""
    calibration = read_calibrations(embedder.info.extra, embedder.path.name).get(result.score)
    if calibration is None or calibration.term(measure) is None or result.statistic is None:
        return result
    confidence, reason = termed(result.statistic, measure, measured, result.score, calibration, setting)
    return replace(result, confidences=[confidence, *result.confidences[1:]], reason=reason)


def _origins(ctx: Context, matches: list[Match]) -> list[float]:
    """`origin_distances` of a run's matches, in the window its query was cut through."""
    p = ctx.patches
    assert p is not None  # `Cut` ran
    measured = ctx.query.distance_mm is None and p.depth is not None
    depth0 = None if p.depth is None else p.depth[0]  # the surface as measured, not as masked
    return origin_distances(ctx.snapshot, matches, p.distance, depth0, ctx.window, measured)


def judged(settings: Settings, embedder: Embedder) -> int:
    """How many answers the open-set verdict reads for this model at these settings: `LISTED` when its
    calibration's statistic reads past the best answer (the lead over the nearest other object), else 0."""
    calibration = read_calibrations(embedder.info.extra, embedder.path.name).get(
        served_score(settings, embedder)
    )
    return LISTED if calibration is not None and calibration.statistic != "distance" else 0


def origin_distances(
    snap: Snapshot,
    matches: Sequence[Match],
    cut_mm: float,
    depth_patch: np.ndarray | None,
    window_mm: float,
    measured: bool,
) -> list[float]:
    """Each match's distance to the object's origin, mm. `cut_mm`: the distance the query was cut at
    (given, or the surface measured at the centre); `measured`: it came from depth, so the surface on
    `depth_patch` (S, S) plus each match's offset is the origin (`cut_mm` for an object without offsets)."""
    if not measured or depth_patch is None:
        return [cut_mm] * len(matches)
    surface = float(surface_depth(depth_patch, cut_mm, window_mm))
    out = []
    for m in matches:
        rec = snap.objects.get(m.object_id)
        offset = None if rec is None else offset_of(rec.extra, m.azimuth, m.elevation)
        out.append(cut_mm if offset is None else surface + offset)
    return out
