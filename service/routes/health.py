"""Liveness, readiness and Prometheus metrics."""

from __future__ import annotations

from fastapi import APIRouter, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST

from service.deps import StateDep
from service.pipeline.calibration import stale
from service.schemas import Health, Ready

PROMETHEUS = {"content": {"text/plain": {"schema": {"type": "string"}}}, "description": "Prometheus text"}

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="The process is up")
def healthz() -> Health:
    return Health(status="ok")


@router.get(
    "/readyz",
    response_model=Ready,
    summary="Models and stores are loaded and start-up work is done (503 until then)",
    responses={503: {"model": Ready}},
)
def readyz(state: StateDep) -> Response:
    snap = state.store.snapshot
    ready = state.ready.is_set()
    problem = state.store.problem()  # a shared store's server unreachable: a load balancer looks elsewhere
    body = Ready(
        status="unavailable" if problem else "ready" if ready else "starting",
        models=state.model_names,
        objects=len(snap.objects),
        templates={m: mi.size for m, mi in snap.models.items()},
        detail=problem
        or (state.startup_error if ready else "making templates of demo objects or changed models"),
        calibration=stale(state.settings, state.embedders),
    )
    return JSONResponse(body.model_dump(), status_code=200 if ready and not problem else 503)


@router.get(
    "/metrics",
    summary="Prometheus metrics: requests, latency, store sizes",
    response_class=Response,
    responses={200: PROMETHEUS},
)
def metrics(state: StateDep) -> Response:
    return Response(state.metrics.render(state.store.snapshot), media_type=CONTENT_TYPE_LATEST)
