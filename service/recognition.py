"""One recognition, as `POST /recognize` runs it: the query decoded and checked
(`service.pipeline.query.decode`), then its model's pipeline (`service.pipeline`).

`posedesc evaluate --protocol service` calls `recognise` itself, so what it measures is what a user of
`POST /recognize` gets; `posedesc bench` times `recognise_decoded`, the part after decoding that
`recognise` calls."""

from __future__ import annotations

import time

from service.errors import ApiError
from service.pipeline.answer import Result
from service.pipeline.query import Decoded, Query, decode
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

    An RGB-D query with a centre of a store holding shape-only and textured objects is answered by the RGB-D
    model over them all, as before: asked apart (`service.pipeline.query.by_model`, as a whole frame is),
    its answer would hold one part's objects only, and the two models' confidences are calibrated apart, so
    neither answer can overrule the other (docs/experiments.md, 2026-12-06)."""
    return state.pipelines[d.modality](q, d, state.store.snapshot, decode_s)
