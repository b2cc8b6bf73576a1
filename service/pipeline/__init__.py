"""The recognition pipeline: decoded images -> the model's patch (and its turns) -> descriptors -> the
store's nearest distinct answers -> their local re-ranking, roll sweep and refinement -> k answers.

One `Pipeline` per model, built once from the settings when the state is (`service.state.AppState`); a
query runs it in a worker thread (never on the event loop) and never waits on a registration: it reads
the store's snapshot as it found it and runs the model's own onnxruntime session. The stages, in order
(`STAGES`), each a module of this package with one call and one frozen config built from the settings:

- `cut` (`query.Cut`): the query cut once per turn (`query_turns`) from a frame or a patch;
- `mask` (`mask.QueryMask`, models with a mask): what is not the object made black and empty;
- `embed`, `search` (`search.Embed`, `search.Search`): the descriptors, the store's nearest answers;
- `local` (`rerank.Rerank`), `sweep` (`sweep.Sweep`), `refine` (`refine.Refine`), for models with
  local features: the re-ranking by the local score (`score.LocalScore`), the roll sweep and the
  refinement;

then the answers' assembly (`answer`: the order, the open-set verdict, the origins), and the pose fit of
the best answers over six degrees of freedom against the frame (`fit.PoseFit`, `pose_fit` answers). Then, in a
colour frame sent with its camera and the object's centre, the colours at the best answer's pose
(`colours.Colours`: its `colour_distance`, and the open-set verdict where the calibration weighs them); in a
frame sent with its depth, its camera and the centre, the share of the best answer's surface the depth leaves
unexplained at its pose (`unexplained.Unexplained`: its `unexplained`, and the verdict where the calibration
weighs it). Each stage gets the
query's frozen `context.Context` and hands on a new one (or None: nothing to do for this query). A stage
that a model or the settings leave out is not in its pipeline (`build` returns None). Adding a stage is a
new module and one line in `STAGES`.

Window classes: each object is seen through the window its size asks for (`index.templates.windows`). A query with a
centre (a frame) is cut once per class among the registered objects, the stages run once per class on a
snapshot that sees that class's objects only, and the answers are merged by distance
(`service.pipeline.answer`); with one class (every store before this) it is one run, as before. A patch
query spans the model's window (the API says so) and is searched against every object.

Roll: a template's in-plane angle is a roll the service can answer, so with templates over the whole
turn (a model trained with roll, or the settings) every answer's in-plane is an estimate. With
`query_turns` n > 1 the query is also cut turned by j * s / n (j < n, s the templates' in-plane step, or
the whole turn when they are upright only): the n patches are embedded in one batch and searched, and a
match of template in-plane θ on the turn by o says the object is rolled θ + o (`crop` undoes o).

`timings_ms` (milliseconds): `decode` (when timed: `service.recognition.recognise`), then each stage that
ran by its name (`cut`, `mask`, `embed`, `search`, `local`, `sweep`, `refine`, `fit`, `colours`,
`unexplained`), then the sums older
readers know: `patch` = cut + mask, `rerank` = local + sweep + refine (when the re-ranking ran), and
`total` (everything above, decode included)."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import replace

from index.features.embed import Embedder
from index.refine.chroma import SurfaceColours
from index.store import Snapshot
from index.templates.register import TemplateConfig
from index.templates.windows import window_classes
from service.errors import ApiError, NoSuchWindow
from service.pipeline.answer import Result, answer, judged, shown
from service.pipeline.colours import Colours
from service.pipeline.context import Context, Stage
from service.pipeline.fit import PoseFit, Shapes, first
from service.pipeline.mask import QueryMask
from service.pipeline.query import FRAME_FIELDS, Cut, Decoded, Query
from service.pipeline.refine import Refine
from service.pipeline.rerank import Rerank
from service.pipeline.search import Embed, Search
from service.pipeline.sweep import Sweep
from service.pipeline.unexplained import Unexplained
from service.settings import Settings

#: every stage in its order; each class's `build(settings, embedder, templates)` makes it for a model, or
#: None when the model or the settings leave it out
STAGES = (Cut, QueryMask, Embed, Search, Rerank, Sweep, Refine)

#: the answers a detection's screening re-ranks (`Pipeline.screening`). 60: on the validation frames, when
#: colour proposals were screened too (docs/experiments.md, "The screening, chosen again"): recall 66.1, AP50
#: 73.1 at 1126 ms of verification a frame; 20 (or 5) 63.5, 71.7 at 1016 ms; none 35.7, 55.5
SCREEN_RERANK = 60

#: timing keys kept as the sums of stages, for readers of the times before the stages were split
SUMS: Mapping[str, tuple[str, ...]] = {"patch": ("cut", "mask"), "rerank": ("local", "sweep", "refine")}


class Pipeline:
    """One model's stages (`stages`), run in order on a query."""

    def __init__(
        self,
        stages: tuple[Stage, ...],
        settings: Settings,
        judged: int = 0,
        fit: PoseFit | None = None,
        colours: Colours | None = None,
        unexplained: Unexplained | None = None,
    ):
        self.stages, self.settings, self.judged = stages, settings, judged
        self.fit, self.colours, self.unexplained = fit, colours, unexplained

    @classmethod
    def build(
        cls,
        settings: Settings,
        embedder: Embedder,
        templates: TemplateConfig,
        shapes: Shapes | None = None,
        on_failure: Callable[[str], None] | None = None,
        surfaces: Callable[[int], SurfaceColours | None] | None = None,
    ) -> Pipeline:
        """The model's stages at these settings; `shapes`: the objects' fit models (None: no pose fit);
        `on_failure`: told the stage's name when a stage fails inside (the pose fit); `surfaces`: the
        objects' surface colours (None: the colours at the answer's pose are not measured,
        `service.pipeline.colours`)."""
        made = (stage.build(settings, embedder, templates) for stage in STAGES)
        fit = PoseFit.build(settings, shapes, on_failure)
        colours = None if surfaces is None else Colours(surfaces, settings.reject_above)
        unexplained = None if fit is None else Unexplained(fit.shapes.depth.get, settings.reject_above)
        stages = tuple(s for s in made if s is not None)
        return cls(stages, settings, judged(settings, embedder), fit, colours, unexplained)

    @classmethod
    def screening(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> Pipeline:
        """A detection's screening (`service.detection.verify`: where around a depth segment its object is
        centred, before the whole pipeline names it there): the same stages up to a shorter re-ranking
        (`SCREEN_RERANK` answers), no roll sweep, no refinement, no pose fit."""
        light = settings.model_copy(update={"rerank": SCREEN_RERANK, "roll_sweep": 0, "pose_fit": 0})
        whole = cls.build(light, embedder, templates)
        return cls(tuple(s for s in whole.stages if s.name != Refine.name), light, whole.judged)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.stages)

    def __call__(self, q: Query, d: Decoded, snapshot: Snapshot, decode_s: float | None = None) -> Result:
        """The k best distinct (object, viewpoint) answers to a decoded query, nearest first.
        `decode_s`: the seconds decoding took, reported as `decode` and counted in `total`."""
        t0 = time.perf_counter()
        spent: dict[str, float] = {}
        runs, refused = [], []
        # the answers the query needs: k, more when the fit re-orders them (then cut back to k)
        k = q.k if self.fit is None else self.fit.considered(q, d)
        asked = q if k == q.k else replace(q, k=k)
        for window, objects in classes(q, d, snapshot):
            seen = snapshot if objects is None else snapshot.within(objects)
            ctx = Context(asked, d, seen, wanted=max(k, self.judged), window_mm=window)
            try:
                runs.append(self.run(ctx, spent))
            except ApiError as e:
                # a class whose window the query's depth finds implausible (too near, too few pixels)
                # is left out while another class takes the query; refused by all, the first says why
                if objects is None:
                    raise
                refused.append(e)
        if not runs:
            raise refused[0]
        result = answer(runs, {}, self.settings)
        if self.fit is not None:
            t = time.perf_counter()
            if (fitted := self.fit(result, runs)) is not None:
                result = fitted
                spent[self.fit.name] = time.perf_counter() - t
            result = shown(first(result, q.k), d.embedder, self.settings.reject_above)
        for look in (self.colours, self.unexplained):
            t = time.perf_counter()
            if look is not None and (measured := look(result, runs)) is not None:
                result = measured
                spent[look.name] = time.perf_counter() - t
        result.timings_ms = timings(spent, time.perf_counter() - t0, decode_s)
        return result

    def run(self, ctx: Context, spent: dict[str, float]) -> Context:
        """The stages on one context; each stage's seconds added to `spent`."""
        for stage in self.stages:
            t = time.perf_counter()
            if (out := stage(ctx)) is not None:
                ctx = out
                spent[stage.name] = spent.get(stage.name, 0.0) + time.perf_counter() - t
        return ctx


def classes(q: Query, d: Decoded, snapshot: Snapshot) -> list[tuple[float | None, frozenset[int] | None]]:
    """The windows a query is cut through (None: the model's) and the objects each searches (None: all):
    one per window class of the snapshot's objects for a query with a centre, the model's window first;
    one window for all when there is one class (or none). A patch spans one window (`Query.window_mm`, the
    model's by default) and is compared with the objects registered through it alone: a patch of another
    window against their templates is another object's view, named with a confidence it has not earned.
    Refused (422) when no registered object has the patch's window."""
    model = d.embedder.info.window_mm
    by = window_classes(snapshot.objects, model)
    if not any(getattr(q, f) is not None for f in FRAME_FIELDS):
        want = model if q.window_mm is None else q.window_mm
        if not by or list(by) == [want]:
            return [(None if want == model else want, None)]
        ids = next((ids for w, ids in by.items() if abs(w - want) <= 0.01), None)
        if ids is None:
            held = ", ".join(f"{w:g}" for w in sorted(by))
            raise NoSuchWindow(
                f"the patch spans a {want:g} mm window (window_mm), which no registered object has: "
                f"registered objects' windows are {held} mm (each object's window_mm in GET /objects); cut "
                "the patch through its object's window and send that window_mm, or send the whole frame "
                "with its camera and the object's centre",
            )
        return [(None if want == model else want, ids)]
    if len(by) <= 1:
        window = next(iter(by), model)
        return [(None if window == model else window, None)]
    return [(w, ids) for w, ids in by.items()]


def timings(spent: Mapping[str, float], total: float, decode: float | None) -> dict[str, float]:
    """`timings_ms` from the stages' seconds (see the module's docstring)."""
    ms = {**({} if decode is None else {"decode": decode}), **spent}
    for name, parts in SUMS.items():
        if parts[0] in spent:
            ms[name] = sum(spent.get(p, 0.0) for p in parts)
    ms["total"] = total + (decode or 0.0)
    return {k: round(v * 1000, 2) for k, v in ms.items()}
