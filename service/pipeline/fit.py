"""The pose fit: after the answers are assembled, each of the best `pose_fit` answers of a frame sent with
its camera is moved from its template's pose (a viewpoint on the template sphere, a roll on the template
grid, the distance the query was cut at) to the pose that best explains the frame, over all six degrees of
freedom: with depth, the mesh's points against the measured surface (`index.refine.depth`: trimmed
point-to-plane ICP); with colour only, the mesh's outline against the image (`index.refine.colour`). A fit
that explains the frame no better than the template's pose leaves the answer where it was.

The fits run on the query's worker thread with numpy and OpenCV, never on the renderer's thread (a
registration's), so a query never waits behind a registration. What they need of each object (points and
normals, outlines) is made once from the stored mesh and kept for the objects used most recently
(`Shapes`). A patch sent with depth is fitted against its own depth in the virtual camera it spans
(`fitted_camera`), its answers re-ordered by the depth as a frame's are; a colour patch is not (not tried: the
colour fit was chosen on frames)."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from typing import TypeVar

import numpy as np

from index.draw import DrawMesh, MeshCache
from index.features.patches import PatchSpec, patch_camera
from index.refine.colour import ColourModel, fit_colour
from index.refine.depth import DepthModel, Outline, fit_depth, outline_of
from index.refine.files import ColourFiles
from index.refine.fit import Fit, failed_at
from service.pipeline.answer import Result
from service.pipeline.context import Context, Decoded, Query
from service.settings import Settings

T = TypeVar("T")
log = logging.getLogger("service")

#: objects whose fit models are kept in memory (each under 1 MB); a query fits a handful of objects. The colour
#: ones are kept in the data dir too (`index.refine.files`): a miss reads one back in about a millisecond
CAPACITY = 64

#: the depth re-ordering's first look at each of its answers (`PoseFit.coarse`): ICP of this many iterations
#: on every COARSE_STEP-th model point; the best `refine` are then fitted fully from where it left them.
#: YCB-V video 0000 (real depth, centre given, the depth model, 20 answers): right object 95 % with 5
#: iterations as with 20, at half the time (docs/experiments.md)
COARSE_ITERATIONS = 5
COARSE_STEP = 3
#: the re-ordering's weight on the area a pose explains (`reranked`). A small object posed on a face of a
#: larger one, or a larger one partly hidden, is told apart by it. Chosen on the validation sets' coarse-look
#: answers re-ordered offline, flat from 0.1 to 1 (YCB-V video 0000, real depth: right object 95.0 -> 98.3 %
#: at each; LM-O validation frames, rendered depth: RGB-D 91.7 % at each, depth 95.0 -> 94.2 %): the middle
#: of that range on a log scale. The product on the same sets: every figure unchanged but LM-O RGB-D < 5 deg
#: (88.7 -> 90.4 %). Checked leave one video out on YCB-V (0.1-1.0): 0.5 names more instances right with the
#: open set off, but made through the whole chain (each video's open set set on the other two) it names as many
#: as served, one fewer on video 0002, and the open set rejects fewer unknowns: 0.3 kept (docs/experiments.md)
EXPLAINED_WEIGHT = 0.3
#: of the answers the depth re-orders (`Settings.depth_rerank`), this many best after the coarse look are fitted
#: fully, then re-ordered again. 3: YCB-V video 0000 (real depth, centre given, the depth model): 20 answers
#: looked at coarsely, the best 3 fitted fully, right object 95.0 % as with all 20 fitted fully, 178 ms a query
#: against 457 ms (docs/experiments.md)
DEPTH_REFINE = 3


class Shapes:
    """Each object's fit models, made from its drawing mesh (`index.draw.MeshCache`, the store's mesh cut
    to the faces a drawing needs) on first use and kept for the `CAPACITY` used most recently. With `files`,
    a colour model (0.2-0.5 s to make) is read from its file when one was kept, and kept when made."""

    def __init__(
        self, meshes: MeshCache[DrawMesh], capacity: int = CAPACITY, files: ColourFiles | None = None
    ):
        self.meshes, self.files = meshes, files
        self.colour: MeshCache[ColourModel] = MeshCache(self._colour, capacity)
        self.depth: MeshCache[DepthModel] = MeshCache(self._made(DepthModel.of), capacity)

    def _colour(self, object_id: int) -> ColourModel | None:
        if self.files is not None and (kept := self.files.read(object_id)) is not None:
            return kept
        made = self._made(ColourModel.of)(object_id)
        if made is not None and self.files is not None:
            self.files.write(object_id, made)
        return made

    def _made(self, of: Callable[[DrawMesh], T]) -> Callable[[int], T | None]:
        """What makes an object's model from its drawing mesh: None for an object without a mesh."""

        def load(object_id: int) -> T | None:
            mesh = self.meshes.get(object_id)
            return None if mesh is None else of(mesh)

        return load

    def needed(self, models: Iterable[str]) -> list[MeshCache]:
        """The caches a query of these models (their modalities) reads: colour with an rgb model (a colour
        frame alone), depth with a depth or RGB-D one."""
        have = set(models)
        caches: list[MeshCache] = [self.colour] if "rgb" in have else []
        if have & {"depth", "rgbd"}:
            caches.append(self.depth)
        return caches

    def prune(self, registered: Sequence[int] | set[int]) -> None:
        """Forgets the objects no longer registered (ids are never reused)."""
        for cache in (self.meshes, self.colour, self.depth):
            cache.prune(registered)


@dataclass(frozen=True)
class PoseFit:
    """The best `count` answers of a result fitted to its frame (`Result.fits`). The mask head's mask is not
    given to the colour fit: as a cue beside the colours it lost on the validation frames (AR 68.8 -> 66.8,
    5 deg 5 cm 28.7 -> 25.2 %; docs/experiments.md).

    Where the user sent the centre and the distance, the colour fit's rotation is kept and its translation
    dropped: the outline moves a translation that was right by about 1 % of the distance (the object's
    silhouette says little about its distance), which cost ADD(-S) < 0.1 d 77.4 -> 67.0 % on the
    validation frames sent with the true centre and distance, while fitting the rotation alone (the
    translation held) gained less under 5 deg (22.6 % against 28.7 %). A detection's own estimates
    (`Query.estimated`) are moved: its distance is off by up to 10 %, which the fit takes to 4-5 %."""

    name = "fit"

    count: int
    shapes: Shapes
    #: with depth, this many best answers fitted and re-ordered by what they explain (`Settings.depth_rerank`);
    #: a detection's verification (its centre estimated) re-orders none: five fits for each of up to 30 places
    #: doubled a YCB-V frame's time (docs/service.md)
    rerank: int = 0
    #: of the re-ordered answers, this many best (after the coarse look) fitted fully (`DEPTH_REFINE`)
    refine: int = 3
    #: called with the stage's name when a fit raises (the service's `Metrics.failed`: counted in /metrics)
    on_failure: Callable[[str], None] | None = None

    @classmethod
    def build(
        cls, settings: Settings, shapes: Shapes | None, on_failure: Callable[[str], None] | None = None
    ) -> PoseFit | None:
        """The fit at these settings (None: off, or no `shapes`, the objects' fit models, to fit with)."""
        if shapes is None or settings.pose_fit == 0:
            return None
        return cls(settings.pose_fit, shapes, settings.depth_rerank, DEPTH_REFINE, on_failure)

    def reordered(self, q: Query) -> int:
        return 0 if q.estimated else self.rerank

    def considered(self, q: Query, d: Decoded) -> int:
        """How many answers a query needs for this step: k, or `rerank` when its depth re-orders them."""
        return max(q.k, self.reordered(q)) if self.reorders(q, d) else q.k

    def reorders(self, q: Query, d: Decoded) -> bool:
        return self.reordered(q) > 1 and d.depth is not None and (q.camera is None or q.u is not None)

    def __call__(self, result: Result, runs: Sequence[Context]) -> Result | None:
        q, d = runs[0].query, runs[0].decoded
        K = fitted_camera(q, d, result.distance_mm)
        if self.count <= 0 or K is None:
            return None
        count = self.count
        if self.reorders(q, d):  # each answer looked at coarsely, re-ordered, the best fitted fully
            result = self.coarse(result, q, d, K)
            count = max(count, self.refine)
        fits: list[Fit | None] = []
        for i, m in enumerate(result.matches[:count]):
            fit = self.tried(q, d, K, m.object_id, *result.pose(i))
            before = result.fits[i] if i < len(result.fits) else None
            failed = fit is not None and fit.failed
            if not failed and (fit is None or (before is not None and before.moved and not fit.moved)):
                fit = before  # the coarse look's pose stands when the full fit fails or finds nothing better
            fits.append(fit)
        fitted = replace(result, fits=fits + list(result.fits[count:]))
        if not self.reorders(q, d):
            return fitted
        assert d.depth is not None  # `reorders`: a frame with depth
        return reranked(fitted, len(fits), self.outlines(fitted, len(fits), d.depth, K))

    def coarse(self, result: Result, q: Query, d: Decoded, K: np.ndarray) -> Result:
        """`result` with its first `reordered` answers fitted coarsely to the depth (`COARSE_ITERATIONS`,
        every `COARSE_STEP`-th point) and re-ordered by what they explain (`reranked`)."""
        fits = [
            self.tried(q, d, K, m.object_id, *result.pose(i), coarse=True)
            for i, m in enumerate(result.matches[: self.reordered(q)])
        ]
        looked = replace(result, fits=fits)
        assert d.depth is not None  # only a frame with depth is re-ordered
        return reranked(looked, len(fits), self.outlines(looked, len(fits), d.depth, K))

    def outlines(self, result: Result, n: int, depth: np.ndarray, K: np.ndarray) -> list[Outline]:
        """What the measured depth shows around and over each of the first `n` answers at its pose
        (`index.refine.depth.outline_of`; zeros for an object without a depth model)."""
        models = [self.shapes.depth.get(m.object_id) for m in result.matches[:n]]
        return [
            Outline(0.0, 0.0) if m is None else outline_of(m, *result.pose(i), K, depth)
            for i, m in enumerate(models)
        ]

    def tried(
        self,
        q: Query,
        d: Decoded,
        K: np.ndarray,
        object_id: int,
        R0: np.ndarray,
        t0: np.ndarray,
        coarse: bool = False,
    ) -> Fit | None:
        """`fit`; when it raises, logged, counted (`on_failure`) and answered `failed_at` the start: the
        answer keeps its template's pose, and whatever is judged by its fit (a detection's depth-fit floor,
        the re-ordering) takes it as explaining nothing. An error is never evidence for an answer."""
        try:
            return self.fit(q, d, K, object_id, R0, t0, coarse)
        except Exception:
            log.exception("the pose fit of object %d failed; its answer keeps its template's pose", object_id)
            if self.on_failure is not None:
                self.on_failure("fit")
            return failed_at(R0, t0)

    def fit(
        self,
        q: Query,
        d: Decoded,
        K: np.ndarray,
        object_id: int,
        R0: np.ndarray,
        t0: np.ndarray,
        coarse: bool = False,
    ) -> Fit | None:
        """One answer's fit: with depth by ICP (`coarse`: the re-ordering's first look), with colour alone by
        its outline; None without a model."""
        if d.depth is not None and (model := self.shapes.depth.get(object_id)) is not None:
            if coarse:
                few = DepthModel(model.points[::COARSE_STEP], model.normals[::COARSE_STEP], model.diameter)
                return fit_depth(d.depth, K, few, R0, t0, iterations=COARSE_ITERATIONS)
            return fit_depth(d.depth, K, model, R0, t0)
        if d.rgb is not None and (cmodel := self.shapes.colour.get(object_id)) is not None:
            fit = fit_colour(d.rgb, K, cmodel, R0, t0)
            if fit.moved and q.distance_mm is not None and not q.estimated:
                fit = replace(fit, t=t0)  # what the user sent is kept: see the class's docstring
            return fit
        return None


def fitted_camera(q: Query, d: Decoded, distance_mm: float) -> np.ndarray | None:
    """The camera a query's answers are fitted in: a frame's with its centre; a patch's with depth, the virtual
    camera it spans (`patch_camera`: its window at the distance it was answered at, at its own size, its
    answers posed on its optical axis), its depth the frame to fit against; None for a whole frame's search,
    a colour patch (not tried: the colour fit was chosen on frames) or a frame without its camera."""
    if q.camera is not None:
        return q.camera if q.u is not None and q.v is not None else None
    if d.depth is None:
        return None
    window = d.embedder.info.window_mm if q.window_mm is None else q.window_mm
    return patch_camera(PatchSpec(d.depth.shape[1], window), distance_mm)


def reranked(result: Result, n: int, outlines: Sequence[Outline] = ()) -> Result:
    """`result` with its first `n` answers re-ordered, best first, by the share of their visible points the
    depth explains at their fitted pose (`index.refine.depth.score_of`, 0-1), plus their confidence (0-1;
    none: 0), less their object's least `beyond` (0-1), plus `EXPLAINED_WEIGHT` times the area their pose
    explains as a share of the largest among them (0-1; `index.refine.depth.Outline`; none given: both 0);
    the rest after them as they were. On real depth of shape-only objects (YCB-V video 0000, centre given,
    the depth model) the best answer was the right object for 25 % of instances and one of the first five
    for 67 %; re-ordered, 67 %; the first 20 re-ordered, 95 % (98 % with the open set off, with or without
    the area). The area took videos 0001 and 0002 from 76 and 73 % to 91 and 78 % (open set off), where
    partly hidden objects had been named after small ones posed on their faces (docs/experiments.md).
    Each answer's confidence and open-set statistic move with it; the verdict is then the new best's
    (`service.pipeline.answer.shown`)."""
    n = min(n, len(result.matches), len(result.fits))
    # an object's least `beyond` among its answers: it tells one object from another, not one pose from another
    least: dict[int, float] = {}
    for i, o in enumerate(outlines[:n]):
        oid = result.matches[i].object_id
        least[oid] = min(least.get(oid, 1.0), o.beyond)
    largest = max((o.explained for o in outlines[:n]), default=0.0)

    def key(i: int) -> float:
        conf = result.confidences[i] if i < len(result.confidences) else None
        past = least.get(result.matches[i].object_id, 0.0)
        area = outlines[i].explained / largest if i < len(outlines) and largest > 0 else 0.0
        return -(depth_evidence(result.fits[i], past, area) + (conf or 0.0))

    order = sorted(range(n), key=key) + list(range(n, len(result.matches)))

    def pick(xs: list) -> list:
        return [xs[i] for i in order if i < len(xs)]

    return replace(
        result,
        matches=pick(result.matches),
        confidences=pick(result.confidences),
        statistics=pick(result.statistics),
        origins_mm=pick(result.origins_mm),
        fits=pick(result.fits),
    )


def depth_evidence(fit: Fit | None, beyond: float, area: float) -> float:
    """What the depth says for an answer at its fitted pose, alike for any model's: the share of its seen
    points the depth explains (none fitted: 0), less how far the measured surface goes on past it (`beyond`),
    plus `EXPLAINED_WEIGHT` times the area it explains as a share of the largest among those compared."""
    return (fit.score if fit is not None else 0.0) - beyond + EXPLAINED_WEIGHT * area


def best_part(
    results: Sequence[Result], shapes: Shapes, depth: np.ndarray, K: np.ndarray, ceiling: float
) -> int:
    """Which of several models' results, each over its own part of the store (a shape-only part of the depth
    model, a textured part of the RGB-D model: `service.recognition`), gives the answer: the index of the one
    whose best answer has the most evidence. First what each kind of answer can show: one its model accepts
    whose colours at its fitted pose are its object's (`Result.colour_distance` at most `ceiling`, the
    service's `detect_colour_ceiling`), then one its model accepts without colours to check (a shape-only
    object), then the rest (rejected, or colours that are another object's). Among equals, `depth_evidence`
    (as `reranked` orders one model's answers, without the confidence: the models are calibrated apart, each
    on its own objects). Chosen on LM-O's validation frames and YCB-V video 0000 among the depth alone and
    acceptance first (docs/experiments.md, "A store of shape-only and textured objects, centre given").
    Ties: the first; a result without answers is never chosen."""
    outlines: list[Outline | None] = []
    for r in results:
        model = shapes.depth.get(r.matches[0].object_id) if r.matches else None
        outlines.append(None if model is None else outline_of(model, *r.pose(0), K, depth))
    largest = max((o.explained for o in outlines if o is not None), default=0.0)

    def evidence(j: int) -> tuple[int, float, int]:
        o, r = outlines[j], results[j]
        if not r.matches:
            return (-1, 0.0, -j)
        area = o.explained / largest if o is not None and largest > 0 else 0.0
        beyond = o.beyond if o is not None else 0.0
        fit = depth_evidence(r.fits[0] if r.fits else None, beyond, area)
        return (shown(r, r.colour_distance, ceiling), fit, -j)

    return max(range(len(results)), key=evidence)


def shown(result: Result, colour: float | None, ceiling: float) -> int:
    """What a part's best answer can show, the first key of `best_part` and of a patch's
    `service.recognition.best_patch_part`: 2 when its model accepts it and its colours there (`colour`, its
    object's against the query's, 0-2) are within `ceiling`; 1 when accepted with no colours to check (a
    shape-only object); 0 when rejected, or its colours are another object's."""
    if result.reason is not None or (colour is not None and colour > ceiling):
        return 0
    return 2 if colour is not None else 1


def first(result: Result, k: int) -> Result:
    """`result` cut to its first `k` answers."""
    return replace(
        result,
        matches=result.matches[:k],
        confidences=result.confidences[:k],
        statistics=result.statistics[:k],
        origins_mm=result.origins_mm[:k],
        fits=result.fits[:k],
    )
