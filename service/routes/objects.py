"""Register, list, show and remove objects."""

from __future__ import annotations

import asyncio
import errno
import gc
import logging
import unicodedata
from pathlib import Path
from typing import Annotated, Literal

from fastapi import APIRouter, File, Form, Query, Response, UploadFile
from fastapi.responses import JSONResponse

from index.geometry.shape_symmetry import AUTO
from index.geometry.symmetry import canonical
from index.geometry.units import LARGEST_MM, ORDINARY_MM, SMALLEST_MM, Units
from index.store import NameTaken, StoreError
from index.templates.mesh import FORMATS_TEXT, MeshError, MeshTooLarge, load_mesh
from index.templates.register import SYMMETRY_FROM_KEY, TEXTURED_KEY
from index.templates.viewpoints import VIEWPOINTS_KEY
from index.templates.windows import DIAMETER_KEY, WINDOW_KEY, object_window
from service.demo import DEMO_KEY
from service.deps import ApiKeyDep, KnownFieldsDep, StateDep
from service.errors import DISK_FULL, ApiError, responses
from service.jobs import Busy, Job
from service.pipeline.query import untextured
from service.schemas import JobAccepted, ObjectCreated, ObjectOut, ObjectsRemoved
from service.state import AppState

router = APIRouter(tags=["objects"])
log = logging.getLogger("service")

MAX_QUEUED = 16  # registrations waiting for the render thread; more is a client hammering us


#: the warning a shape-only mesh's registration answers with
SHAPE_ONLY = (
    "the mesh has no colours (no texture, no vertex or face colours): it is recognised by its shape, surely "
    "with depth; in colour only at a centre you give (u, v), by its silhouette and shading, at lower "
    "confidence: a whole colour frame does not search for it"
)


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
        demo=bool(rec.extra.get(DEMO_KEY)),
        diameter_mm=_number(rec.extra.get(DIAMETER_KEY)),
        window_mm=object_window(rec.extra, min(e.info.window_mm for e in state.embedders.values())),
        textured=_flag(rec.extra.get(TEXTURED_KEY)),
        symmetry_from=_text(rec.extra.get(SYMMETRY_FROM_KEY)),
        viewpoints=_text(rec.extra.get(VIEWPOINTS_KEY)),
    )


def _number(x: object) -> float | None:
    return float(x) if isinstance(x, (int, float)) else None


def _flag(x: object) -> bool | None:
    return x if isinstance(x, bool) else None


def _text(x: object) -> str | None:
    return x if isinstance(x, str) else None


@router.post(
    "/objects",
    status_code=201,
    response_model=ObjectCreated,
    summary="Register a mesh: 201 when done within ~2 s, else 202 with a job to poll",
    responses={
        202: {"model": JobAccepted, "description": "still registering: poll /jobs/{job_id}"},
        **responses(400, 401, 403, 409, 413, 422, 503, 507),
    },
    dependencies=[KnownFieldsDep],
)
async def add_object(
    state: StateDep,
    _key: ApiKeyDep,
    mesh: Annotated[UploadFile, File(description=f"{FORMATS_TEXT}; vertex colours or a texture (GLB, glTF)")],
    name: Annotated[str, Form(min_length=1, max_length=200, examples=["my-part"])],
    units: Annotated[
        Units | None,
        Form(
            description=f"units of the mesh file; an object whose diameter comes out under {SMALLEST_MM:g} or "
            f"over {LARGEST_MM:g} mm is refused, with the units that would fit. Not given: mm, but an object "
            f"outside {ORDINARY_MM[0]:g}-{ORDINARY_MM[1]:g} mm that another unit would put inside is refused "
            "until the units are given"
        ),
    ] = None,
    symmetry: Annotated[
        str,
        Form(
            max_length=100,
            description="the turns that leave it looking the same: 'none', '180' (a half-turn about z), "
            "'full' (any turn about z), each with '+flip' (and end over end: a half-turn about x, or "
            "'+flip@30' about the axis 30 degrees from x in the xy plane; 'flip' alone); '180+flip' is a box, "
            "'full+flip' a can with both ends alike; 'x:' or 'y:' before it: about that axis in place of z "
            "('y:full+flip', a pen lying along y). 'auto': 'none' for a mesh with colours (a texture, "
            "vertex or face colours), and for a shape-only mesh the symmetry of its shape",
            examples=["auto"],
        ),
    ] = "auto",
    viewpoints: Annotated[
        Literal["upper", "sphere"] | None,
        Form(
            description="where its templates are seen from: 'upper', the half above the mesh's xy plane (an "
            "object that stands as its z axis points up, as a scan usually does); 'sphere', every side (an "
            "object that may lie on any face, as a CAD file's axes say nothing of how it lies: twice the "
            "templates and the registration's time). Not given: the service's POSEDESC_VIEWPOINTS (upper)"
        ),
    ] = None,
) -> Response | ObjectCreated:
    if not name.strip() or any(unicodedata.category(c) == "Cc" for c in name):
        raise ApiError(
            422,
            "name: it must show at least one character and hold no control characters (newline, tab, NUL)",
        )
    if symmetry != AUTO:
        try:
            symmetry = canonical(symmetry)
        except ValueError as e:
            raise ApiError(422, f"symmetry: {e}") from None
    file_type = Path(mesh.filename or "").suffix.lstrip(".").lower()
    if not file_type:
        raise ApiError(422, f"mesh: the file name needs an extension: {FORMATS_TEXT}")
    if (same := state.store.snapshot.named(name)) is not None:  # at once, before the upload is parsed
        raise ApiError(409, _taken(NameTaken(name, same.object_id)))
    try:  # the job holds its place in the queue from here on, so concurrent uploads cannot all pass
        job = state.jobs.new(name, limit=MAX_QUEUED)
    except Busy:
        raise ApiError(503, "too many registrations queued; try again in a minute") from None
    try:
        loaded = await _load_upload(state, mesh, units, file_type)
        fut = state.registrar.submit(_run, state, job, loaded, name, symmetry, viewpoints)
    except BaseException:  # refused, cancelled (the client left) or shutting down: it frees its place
        state.jobs.discard(job)
        raise
    try:
        await asyncio.wait_for(asyncio.shield(asyncio.wrap_future(fut)), state.settings.sync_seconds)
    except TimeoutError:
        body = JobAccepted(job_id=job.job_id, status="running").model_dump()
        return JSONResponse(body, status_code=202, headers={"Location": f"/jobs/{job.job_id}"})
    if job.status == "failed":
        raise ApiError(job.code or 500, job.error or "registration failed")
    return ObjectCreated(**job.result)  # type: ignore[arg-type]


async def _load_upload(state: AppState, mesh: UploadFile, units: str | None, file_type: str):
    """The uploaded mesh, parsed on the mesh thread (413/422 when unusable)."""
    limits = state.settings.max_faces, state.settings.max_upload_faces
    async with state.mesh_gate:  # meanwhile the other uploads wait spooled to disk, not in memory
        data = await mesh.read()
        try:
            loaded = await asyncio.wrap_future(
                state.mesh_loader.submit(_load, data, units, file_type, *limits)
            )
        except MeshTooLarge as e:
            raise ApiError(413, f"mesh: {e}") from None
        except MeshError as e:
            raise ApiError(422, f"mesh: {e}") from None
        del data
    return loaded


def _taken(e: NameTaken) -> str:
    return f"{e}: delete it first, or choose another name"


#: uploads up to this size leave too little behind to be worth a full GC on the request's path (`_load`)
SMALL_UPLOAD = 4 << 20


def _load(data: bytes, units: str | None, file_type: str, max_faces: int, max_upload_faces: int):
    """`load_mesh` on the mesh thread, leaving nothing behind: trimesh's meshes are reference cycles
    (mesh <-> visual), so a refused or simplified one would stay in memory until the next full GC and
    the next upload's parse stack on it (measured: +750 MB for three 12 M-triangle files in a row).
    A mesh taken from a small file (`SMALL_UPLOAD`: 200k faces of binary PLY) leaves a few MB at most,
    while a full GC of the service's ~200k objects takes 0.2-0.3 s on 2 cores: after one, only the young
    objects (the parse's own) are collected."""
    young = len(data) <= SMALL_UPLOAD
    try:
        return load_mesh(data, units, file_type, max_faces, max_upload_faces, check_size=True)
    except MeshError as e:
        young = False
        raise e.with_traceback(None) from None  # its frames hold the parsed mesh
    except BaseException:
        young = False
        raise
    finally:
        gc.collect(1 if young else 2)


def _run(state: AppState, job: Job, mesh, name: str, symmetry: str, viewpoints: str | None = None) -> None:
    """The registration, on the registration thread; its outcome goes into the job (shared with the other
    replicas when the store is)."""
    try:
        _register(state, job, mesh, name, symmetry, viewpoints)
    finally:
        state.jobs.save(job)


def _register(state: AppState, job: Job, mesh, name: str, symmetry: str, viewpoints: str | None) -> None:
    def progress(stage: str, done: int, total: int) -> None:
        job.advance(stage, done, total)
        state.jobs.save(job)  # where the other replicas read it, with a shared store

    try:
        reg = state.register_mesh(mesh, name, symmetry, progress=progress, viewpoints=viewpoints)
    except MeshError as e:
        job.fail(422, f"mesh: {e}")
        return
    except NameTaken as e:  # registered meanwhile, by an upload queued before this one (or another replica)
        job.fail(409, _taken(e))
        return
    except StoreError as e:  # the Milvus store does not answer: nothing is live (a pending rest is swept)
        job.fail(503, f"{e}; nothing was registered")
        return
    except Exception as e:
        if isinstance(e, OSError) and e.errno == errno.ENOSPC:  # rolled back: nothing was stored
            log.error("registration of %s: %s", name, e)
            job.fail(507, DISK_FULL)
        else:
            log.exception("registration of %s failed", name)
            job.fail(500, f"registration failed: {type(e).__name__}: {e}")
        return
    state.metrics.observe_registration(reg.timings)
    job.result = ObjectCreated(
        object_id=reg.record.object_id,
        name=name,
        templates=max(reg.record.templates.values()),
        seconds=round(reg.timings["total"], 3),
        timings={k: round(v, 3) for k, v in reg.timings.items()},
        diameter_mm=float(reg.record.extra[DIAMETER_KEY]),  # type: ignore[arg-type]  # register stores it
        window_mm=float(reg.record.extra[WINDOW_KEY]),  # type: ignore[arg-type]
        symmetry=reg.record.symmetry,
        textured=_flag(reg.record.extra.get(TEXTURED_KEY)),
        symmetry_from=_text(reg.record.extra.get(SYMMETRY_FROM_KEY)),
        viewpoints=_text(reg.record.extra.get(VIEWPOINTS_KEY)),
        warnings=[SHAPE_ONLY] if untextured(reg.record) else [],
    ).model_dump()
    job.status = "done"


@router.get("/objects", response_model=list[ObjectOut], summary="All registered objects")
def list_objects(state: StateDep) -> list[ObjectOut]:
    snap = state.store.snapshot
    return [_out(state, oid) for oid in sorted(snap.objects)]


@router.get(
    "/objects/{object_id}", response_model=ObjectOut, summary="One object", responses=responses(404, 422)
)
def get_object(object_id: int, state: StateDep) -> ObjectOut:
    return _out(state, object_id)


@router.delete(
    "/objects",
    response_model=ObjectsRemoved,
    summary="Remove the demo objects (demo=true): the one call that clears a new data dir for your own",
    responses=responses(401, 422, 507),
)
def delete_demo_objects(
    state: StateDep,
    _key: ApiKeyDep,
    demo: Annotated[
        bool, Query(description="true: remove every demo object (they do not come back)")
    ] = False,
) -> ObjectsRemoved:
    if not demo:
        raise ApiError(
            422,
            "DELETE /objects removes the demo objects only, with ?demo=true; one object: DELETE /objects/{id}",
        )
    snap = state.store.snapshot
    gone = [oid for oid, rec in sorted(snap.objects.items()) if rec.extra.get(DEMO_KEY)]
    removed = [oid for oid in gone if state.remove(oid)]  # one may go meanwhile (a replica)
    return ObjectsRemoved(removed=removed)


@router.delete(
    "/objects/{object_id}",
    status_code=204,
    summary="Remove an object and all its templates",
    responses=responses(401, 404, 422, 507),
)
def delete_object(object_id: int, state: StateDep, _key: ApiKeyDep) -> Response:
    if not state.remove(object_id):
        raise ApiError(404, f"no object {object_id}")
    return Response(status_code=204)
