"""One recognition, as `POST /recognize` runs it: the query decoded and checked
(`service.pipeline.query.decode`), then its model's pipeline (`service.pipeline`).

`posedesc evaluate --protocol service` calls `recognise` itself, so what it measures is what a user of
`POST /recognize` gets; `posedesc bench` times `recognise_decoded`, the part after decoding that
`recognise` calls."""

from __future__ import annotations

import time

from service.pipeline.answer import Result
from service.pipeline.query import Decoded, Query, decode
from service.state import AppState


def recognise(state: AppState, q: Query) -> Result:
    """What `POST /recognize` answers: the k best distinct (object, viewpoint) answers, nearest first."""
    t0 = time.perf_counter()
    d = decode(state, q)
    return recognise_decoded(state, q, d, decode_s=time.perf_counter() - t0)


def recognise_decoded(state: AppState, q: Query, d: Decoded, decode_s: float | None = None) -> Result:
    """From decoded images to the answer, what `recognise` (so the route) runs after `decode`: the
    pipeline of the model the query's modality picked. `posedesc bench` times this call. `decode_s`: the
    seconds decoding took, reported as `decode` and counted in `total` (omitted when None)."""
    return state.pipelines[d.modality](q, d, state.store.snapshot, decode_s)
