"""Recognition: which known object is at the given place of an image, and seen from where."""

from __future__ import annotations

import asyncio
from typing import Annotated

from fastapi import APIRouter, File, Form, UploadFile

from service.deps import KnownFieldsDep, StateDep
from service.errors import responses
from service.pipeline.query import MAX_DISTANCE_MM, MAX_PX, MIN_DISTANCE_MM, Query
from service.poses import pose_fields
from service.recognition import recognise
from service.schemas import MatchOut, RecognizeOut

router = APIRouter(tags=["recognition"])


@router.post(
    "/recognize",
    response_model=RecognizeOut,
    summary="The k nearest distinct poses of a patch, or of the object at (u, v) in a full frame",
    description=(
        "Send `rgb` (PNG/JPEG) and/or `depth` (16-bit PNG, mm x `depth_scale`): the modality picks the "
        "model. Either a square patch already centred on the object and spanning the model's metric "
        "window, or a full frame with intrinsics `fx`, `fy`, `cx`, `cy` and the object's centre `u`, `v` "
        "(pixels, where the object's origin projects). `distance_mm` is the distance from the camera "
        "centre to the object's origin along the ray through (u, v) (‖t‖ of a BOP pose); a colour-only "
        "frame needs it. With depth and no `distance_mm`, the service measures the surface at (u, v) and "
        "cuts the patch there; each answer then puts the origin behind that surface by its template's "
        "offset (how far the origin of that object lies behind the surface seen from that viewpoint). The answer holds `k` distinct (object, viewpoint) "
        "matches, nearest first, each with its azimuth, elevation and estimated in-plane angle (roll, "
        "counter-clockwise in the image, in (-180, 180]; 0 when the templates are upright only) and its pose "
        "in the camera as BOP writes it: `R` (model to camera, row-major) and `t` (mm) along the ray through "
        "(u, v) at the object's origin: `distance_mm` when sent, else the measured surface plus the answer's "
        "offset (for a patch, in the patch's own camera). `best` is null, "
        "with a `reason`, when the nearest answer is too far to be a registered object (open-set rejection: "
        "each model's calibrated threshold, or the REJECT_ABOVE setting); each match's `confidence` is the "
        "calibrated chance that it is the right object."
    ),
    responses=responses(400, 413, 422),
    dependencies=[KnownFieldsDep],
)
async def recognize(
    state: StateDep,
    rgb: Annotated[UploadFile | None, File(description="colour image, PNG or JPEG")] = None,
    depth: Annotated[UploadFile | None, File(description="depth image, 16-bit PNG")] = None,
    depth_scale: Annotated[float, Form(gt=0, le=1000, allow_inf_nan=False, description="mm per unit")] = 1.0,
    # Bounds keep the camera matrices invertible: a focal length of 5e-324 px is no camera.
    fx: Annotated[float | None, Form(ge=1, le=MAX_PX, description="focal x, px", examples=[572.4])] = None,
    fy: Annotated[float | None, Form(ge=1, le=MAX_PX, description="focal y, px", examples=[573.6])] = None,
    cx: Annotated[
        float | None, Form(ge=-MAX_PX, le=MAX_PX, description="principal point x, px", examples=[325.3])
    ] = None,
    cy: Annotated[
        float | None, Form(ge=-MAX_PX, le=MAX_PX, description="principal point y, px", examples=[242.0])
    ] = None,
    u: Annotated[
        float | None,
        Form(ge=-MAX_PX, le=MAX_PX, description="object centre x in the frame, px", examples=[380.0]),
    ] = None,
    v: Annotated[
        float | None,
        Form(ge=-MAX_PX, le=MAX_PX, description="object centre y in the frame, px", examples=[250.0]),
    ] = None,
    distance_mm: Annotated[
        float | None,
        Form(
            ge=MIN_DISTANCE_MM,
            le=MAX_DISTANCE_MM,
            description="from the camera centre to the object's origin along the ray through (u, v), mm "
            "(optional with depth: then the surface at (u, v) is measured and each answer adds how far its "
            "template's origin lies behind the surface)",
        ),
    ] = None,
    k: Annotated[
        int, Form(ge=1, description="how many distinct (object, viewpoint) answers", examples=[5])
    ] = 5,
) -> RecognizeOut:
    async with state.recognition_gate:  # bounds the memory of decoded images; waiting ones stay spooled
        q = Query(
            rgb=await rgb.read() if rgb is not None else None,
            depth=await depth.read() if depth is not None else None,
            depth_scale=depth_scale,
            fx=fx,
            fy=fy,
            cx=cx,
            cy=cy,
            u=u,
            v=v,
            distance_mm=distance_mm,
            k=k,
        )
        result = await asyncio.wrap_future(state.recognizer.submit(recognise, state, q))
    matches = [
        MatchOut(**m.__dict__, confidence=c, **pose_fields(m, result.ray, origin))
        for m, c, origin in zip(result.matches, result.confidences, result.origins_mm, strict=True)
    ]
    return RecognizeOut(
        matches=matches,
        best=None if result.reason else matches[0],
        reason=result.reason,
        score=result.score,
        timings_ms=result.timings_ms,
        model=result.model,
    )
