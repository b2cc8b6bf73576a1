"""Register, list, show and remove objects."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, File, Form, Response, UploadFile
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from index.mesh import MeshError, load_mesh, scale_warning
from index.register import register
from service.deps import ApiKeyDep, StateDep
from service.errors import ApiError
from service.jobs import Job
from service.schemas import JobAccepted, ObjectCreated, ObjectOut
from service.state import AppState

router = APIRouter(tags=["objects"])
log = logging.getLogger("service")

MAX_QUEUED = 16  # registrations waiting for the render thread; more is a client hammering us
ERRORS = {
    401: {"description": "missing or wrong API key"},
    413: {"description": "upload over the size limit"},
    422: {"description": "not a mesh, an empty or degenerate mesh, a bad field"},
}


def _out(state: AppState, object_id: int) -> ObjectOut:
    rec = state.store.snapshot.objects.get(object_id)
    if rec is None:
        raise ApiError(404, f"no object {object_id}")
    return ObjectOut(
        object_id=rec.object_id,
        name=rec.name,
        symmetry=rec.symmetry,
        faces=rec.faces,
        templates=dict(rec.templates),
        created=rec.created,
    )


@router.post(
    "/objects",
    status_code=201,
    response_model=ObjectCreated,
    summary="Register a mesh: 201 when done within ~2 s, else 202 with a job to poll",
    responses={
        202: {"model": JobAccepted, "description": "still registering: poll /jobs/{job_id}"},
        **ERRORS,
    },
)
async def add_object(
    state: StateDep,
    _key: ApiKeyDep,
    mesh: Annotated[UploadFile, File(description="PLY, OBJ, STL or GLB; vertex colours or a texture")],
    name: Annotated[str, Form(min_length=1, max_length=200, examples=["my-part"])],
    units: Annotated[Literal["mm", "m"], Form(description="units of the mesh file")] = "mm",
    symmetry: Annotated[
        Literal["none", "180", "full"], Form(description="about the object's z axis")
    ] = "none",
) -> Response | ObjectCreated:
    data = await mesh.read()
    file_type = Path(mesh.filename or "").suffix.lstrip(".").lower()
    if not file_type:
        raise ApiError(422, "mesh: the file name needs an extension (.ply, .obj, .stl or .glb)")
    if state.jobs.running() >= MAX_QUEUED:
        raise ApiError(503, "too many registrations queued; try again in a minute")
    try:
        loaded = await run_in_threadpool(load_mesh, data, units, file_type, state.settings.max_faces)
    except MeshError as e:
        raise ApiError(422, f"mesh: {e}") from None
    window = min(e.info.window_mm for e in state.embedders.values())
    warnings = [w for w in [scale_warning(loaded, window)] if w]
    job = state.jobs.new(name)
    fut = state.registrar.submit(_run, state, job, loaded, name, symmetry, warnings)
    try:
        await asyncio.wait_for(asyncio.shield(asyncio.wrap_future(fut)), state.settings.sync_seconds)
    except TimeoutError:
        body = JobAccepted(job_id=job.job_id, status="running").model_dump()
        return JSONResponse(body, status_code=202, headers={"Location": f"/jobs/{job.job_id}"})
    if job.status == "failed":
        raise ApiError(422 if job.error and job.error.startswith("mesh:") else 500, job.error or "failed")
    return ObjectCreated(**job.result)  # type: ignore[arg-type]


def _run(state: AppState, job: Job, mesh, name: str, symmetry: str, warnings: list[str]) -> None:
    """The registration, on the registration thread; its outcome goes into the job."""
    try:
        reg = register(
            mesh,
            name,
            symmetry,
            worker=state.worker,
            embedders=state.embedders,
            store=state.store,
            cfg=state.templates,
            pool=state.embed_pool,
        )
    except MeshError as e:
        job.error, job.status = f"mesh: {e}", "failed"
        return
    except Exception as e:
        log.exception("registration of %s failed", name)
        job.error, job.status = f"registration failed: {type(e).__name__}: {e}", "failed"
        return
    state.metrics.observe_registration(reg.timings)
    job.result = ObjectCreated(
        object_id=reg.record.object_id,
        name=name,
        templates=max(reg.record.templates.values()),
        seconds=round(reg.timings["total"], 3),
        timings={k: round(v, 3) for k, v in reg.timings.items()},
        warnings=warnings,
    ).model_dump()
    job.status = "done"


@router.get("/objects", response_model=list[ObjectOut], summary="All registered objects")
def list_objects(state: StateDep) -> list[ObjectOut]:
    snap = state.store.snapshot
    return [_out(state, oid) for oid in sorted(snap.objects)]


@router.get("/objects/{object_id}", response_model=ObjectOut, responses={404: {"description": "unknown id"}})
def get_object(object_id: int, state: StateDep) -> ObjectOut:
    return _out(state, object_id)


@router.delete(
    "/objects/{object_id}",
    status_code=204,
    summary="Remove an object and all its templates",
    responses={401: ERRORS[401], 404: {"description": "unknown id"}},
)
def delete_object(object_id: int, state: StateDep, _key: ApiKeyDep) -> Response:
    if not state.store.remove_object(object_id):
        raise ApiError(404, f"no object {object_id}")
    return Response(status_code=204)
