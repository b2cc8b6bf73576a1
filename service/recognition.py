"""One recognition, as `POST /recognize` runs it: the query decoded and checked
(`service.pipeline.query.decode`), then its model's pipeline (`service.pipeline`).

`posedesc evaluate --protocol service` calls `recognise` itself, so what it measures is what a user of
`POST /recognize` gets; `posedesc bench` times `recognise_decoded`, the part after decoding that
`recognise` calls."""

from __future__ import annotations

import time

from service.errors import ApiError
from service.pipeline.answer import Result
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

    An RGB-D query of a store holding shape-only and textured objects asks each part its own model
    (`service.pipeline.query.by_model`: the shape-only objects the depth model) and answers with the
    more confident of the two: an answer the open set accepts before one it rejects, then the higher
    calibrated confidence of the best match (each model's own calibration)."""
    parts = by_model(state, d)
    results = [state.pipelines[dp.modality](q, dp, snapshot, decode_s) for dp, snapshot in parts]
    return max(results, key=_trust) if len(results) > 1 else results[0]


def _trust(result: Result) -> tuple[bool, float]:
    """How far an answer is to be believed: accepted by the open set, then its best match's confidence."""
    confidence = result.confidences[0] if result.matches and result.confidences else None
    return result.reason is None and bool(result.matches), confidence or 0.0
