"""One recognition, as `POST /recognize` runs it: the query decoded and checked
(`service.pipeline.query.decode`), then its model's pipeline (`service.pipeline`).

`posedesc evaluate --protocol service` calls `recognise` itself, so what it measures is what a user of
`POST /recognize` gets; `posedesc bench` times `recognise_decoded`, the part after decoding that
`recognise` calls."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

from service.errors import ApiError, NoSuchWindow
from service.pipeline.answer import Result
from service.pipeline.colours import patch_colour_distance
from service.pipeline.fit import best_part, shown
from service.pipeline.query import Decoded, Query, by_model, decode
from service.state import AppState


def answerable(state: AppState) -> None:
    """Refuses (503, with the store's reason) a query this replica cannot answer as every other replica
    would: a shared store out of reach, or this replica without the files the store's objects need
    (`index.store.milvus_trust`). Answering from part of an object would be a wrong answer with a 200."""
    if (problem := state.store.problem()) is not None:
        raise ApiError(503, problem)


def recognise(state: AppState, q: Query) -> Result:
    """What `POST /recognize` answers: the k best distinct (object, viewpoint) answers, nearest first."""
    answerable(state)
    t0 = time.perf_counter()
    d = decode(state, q)
    return recognise_decoded(state, q, d, decode_s=time.perf_counter() - t0)


def recognise_decoded(state: AppState, q: Query, d: Decoded, decode_s: float | None = None) -> Result:
    """From decoded images to the answer, what `recognise` (so the route) runs after `decode`: the
    pipeline of the model the query's modality picked. `posedesc bench` times this call. `decode_s`: the
    seconds decoding took, reported as `decode` and counted in `total` (omitted when None).

    An RGB-D frame sent with its camera and the object's centre, of a store holding shape-only and textured
    objects, is asked of each part's model, as a whole frame is (`service.pipeline.query.by_model`: the
    shape-only objects of the depth model, whose templates have no colours to miss), and the answer is the
    part's whose best answer shows the most (`service.pipeline.fit.best_part`: accepted with its colours,
    accepted, then what the depth explains at its fitted pose), its other answers after. Asked of the RGB-D
    model alone, as before, YCB-V's shape-only objects beside LM-O's textured ones were named right 0, 0 and
    20 % of the time on its three videos; now 95.0 % on video 0000, which chose the rule with LM-O's
    validation frames, and 73.8 and 77.5 % on the other two (docs/experiments.md, "A store of shape-only and
    textured objects, centre given"). An RGB-D patch of such a store (no camera) is split alike
    and answered by the part `best_patch_part` picks: YCB-V's objects beside LM-O's, right 0, 0 and 17.5 % of
    their patches before, now 100.0 % on video 0000 (which chose the rule with LM-O's validation patches),
    68.8 and 65.0 % on the other two (the patches fitted); LM-O's test patches lost 3 of 107 (docs/experiments.md,
    "An RGB-D patch of a store of shape-only and textured objects", "A patch with depth fitted")."""
    parts = by_model(state, d) if split(q, d) else []
    if len(parts) < 2:
        return state.pipelines[d.modality](q, d, state.store.snapshot, decode_s)

    def asked(i: int) -> Result | ApiError:
        part, snapshot = parts[i]
        try:  # a part whose windows the depth finds implausible is left out while the other answers
            return state.pipelines[part.modality](q, part, snapshot, decode_s if i == 0 else None)
        except ApiError as e:
            return e

    # side by side on the pool a frame's places are verified on (`Settings.detect_threads`), this thread waiting
    outcomes = list(state.verifier.map(asked, range(len(parts))))
    results = [r for r in outcomes if isinstance(r, Result)]
    refused = [e for e in outcomes if isinstance(e, ApiError)]
    if not results:  # the reason of a part that has the patch's window, rather than "no object has it"
        raise next((e for e in refused if not isinstance(e, NoSuchWindow)), refused[0])
    if len(results) < 2:
        best = 0
    elif q.camera is None:  # a patch: no frame to fit against, its colours at each answer's template pose
        window = d.embedder.info.window_mm if q.window_mm is None else q.window_mm
        colours = [patch_colour_distance(state.surfaces.get, d, window, r) for r in results]
        best = best_patch_part(results, colours, state.settings.detect_colour_ceiling)
    else:
        assert d.depth is not None  # `split`
        best = best_part(results, state.shapes, d.depth, q.camera, state.settings.detect_colour_ceiling)
    return followed(results[best], [r for i, r in enumerate(results) if i != best], q.k)


def split(q: Query, d: Decoded) -> bool:
    """Whether the query is asked of each part of a mixed store (`recognise_decoded`): an RGB-D frame with
    its camera and centre, which the depth can judge each part's answer on, or an RGB-D patch (no camera),
    judged by its colours and each model's verdict (`best_patch_part`). A whole frame (a camera, no centre) is the detection's,
    which splits it itself."""
    return d.modality == "rgbd" and d.depth is not None and (q.camera is None or q.u is not None)


def best_patch_part(results: Sequence[Result], colours: Sequence[float | None], ceiling: float) -> int:
    """Which part's result answers a patch (no camera): as `best_part` ranks what each kind of answer can show,
    an answer its model accepts whose colours in the patch at its pose are its object's (`colours`, each
    result's best answer's `service.pipeline.colours.patch_colour_distance`, at most `ceiling`), then one
    accepted without colours to check (a shape-only object), then the rest; among equals the more confident
    (each model's curve, `service.rejection`, maps its statistic to the share of such answers that were right;
    the depth's evidence in the patch's camera instead named the same on the sets that chose the rule:
    docs/experiments.md, "A patch with depth fitted"). Ties: the first; a result without answers is never
    chosen."""

    def evidence(j: int) -> tuple[int, float, int]:
        r = results[j]
        if not r.matches:
            return (-1, 0.0, -j)
        confidence = r.confidences[0] if r.confidences and r.confidences[0] is not None else 0.0
        return (shown(r, colours[j], ceiling), confidence, -j)

    return max(range(len(results)), key=evidence)


def followed(result: Result, others: list[Result], k: int) -> Result:
    """`result` with the answers of `others` after its own, cut to `k`; the verdict, the measures of the best
    answer and the model are `result`'s, the stages' times those of all of them."""
    fits = list(result.fits) + [None] * (len(result.matches) - len(result.fits))
    matches = list(result.matches)
    confidences = list(result.confidences) + [None] * (len(matches) - len(result.confidences))
    statistics, origins = list(result.statistics), list(result.origins_mm)
    timings = dict(result.timings_ms)
    for o in others:
        matches += o.matches
        confidences += o.confidences + [None] * (len(o.matches) - len(o.confidences))
        statistics += o.statistics if len(statistics) == len(matches) - len(o.matches) else []
        origins += o.origins_mm
        fits += list(o.fits) + [None] * (len(o.matches) - len(o.fits))
        for name, ms in o.timings_ms.items():
            timings[name] = round(timings.get(name, 0.0) + ms, 2)
    return replace(
        result,
        matches=matches[:k],
        confidences=confidences[:k],
        statistics=statistics[:k],
        origins_mm=origins[:k],
        fits=fits[:k],
        timings_ms=timings,
    )
