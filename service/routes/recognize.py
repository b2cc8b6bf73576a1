"""Recognition: which known object is at the given place of an image, and seen from where."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, replace
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Depends, File, Form, Response, UploadFile

from index.draw import PATCH_DRAW_PX
from service.answers import answer, drawing
from service.deps import KnownFieldsDep, StateDep
from service.errors import ApiError, responses
from service.inputs.camera import MAX_PX, coefficients, intrinsics, undistorted_point
from service.pipeline.query import MAX_DISTANCE_MM, Query
from service.schemas import RecognizeOut

router = APIRouter(tags=["recognition"])

MAX_DETECTIONS = 100  # objects one frame's answer reports at most


@dataclass(frozen=True)
class RecognizeForm:
    """What `/recognize` takes (and `/recognize/draw`): the uploaded images, unread, and the other
    fields (`fields`, a query without its images)."""

    rgb: UploadFile | None
    depth: UploadFile | None
    fields: Query

    async def query(self) -> Query:
        """The query, its images read: call it inside `recognition_gate`."""
        return replace(
            self.fields,
            rgb=await self.rgb.read() if self.rgb is not None else None,
            depth=await self.depth.read() if self.depth is not None else None,
        )


async def recognize_form(
    rgb: Annotated[UploadFile | None, File(description="colour image, PNG or JPEG")] = None,
    depth: Annotated[
        UploadFile | None, File(description="depth: a 16-bit PNG (mm), or float32 metres as .npy or TIFF")
    ] = None,
    depth_scale: Annotated[
        float | None,
        Form(
            gt=0,
            le=1000,
            allow_inf_nan=False,
            description="mm per depth unit (default: the file's own: mm for a 16-bit PNG, metres for float depth)",
        ),
    ] = None,
    # Bounds keep the camera matrices invertible: a focal length of 5e-324 px is no camera.
    fx: Annotated[
        float | None, Form(ge=1, le=MAX_PX, allow_inf_nan=False, description="focal x, px", examples=[572.4])
    ] = None,
    fy: Annotated[
        float | None, Form(ge=1, le=MAX_PX, allow_inf_nan=False, description="focal y, px", examples=[573.6])
    ] = None,
    cx: Annotated[
        float | None,
        Form(
            ge=-MAX_PX, le=MAX_PX, allow_inf_nan=False, description="principal point x, px", examples=[325.3]
        ),
    ] = None,
    cy: Annotated[
        float | None,
        Form(
            ge=-MAX_PX, le=MAX_PX, allow_inf_nan=False, description="principal point y, px", examples=[242.0]
        ),
    ] = None,
    u: Annotated[
        float | None,
        Form(
            ge=-MAX_PX,
            le=MAX_PX,
            allow_inf_nan=False,
            description="object centre x in the frame, px",
            examples=[380.0],
        ),
    ] = None,
    v: Annotated[
        float | None,
        Form(
            ge=-MAX_PX,
            le=MAX_PX,
            allow_inf_nan=False,
            description="object centre y in the frame, px",
            examples=[250.0],
        ),
    ] = None,
    distance_mm: Annotated[
        float | None,
        Form(
            gt=0,  # below `PLAUSIBLE_DISTANCE_MM` refused with a hint (metres?) by `check_camera`
            le=MAX_DISTANCE_MM,
            allow_inf_nan=False,
            description="from the camera centre to the object's origin along the ray through (u, v), mm "
            "(optional with depth: then the surface at (u, v) is measured and each answer adds how far its "
            "template's origin lies behind the surface)",
        ),
    ] = None,
    k: Annotated[
        int, Form(ge=1, description="how many distinct (object, viewpoint) answers", examples=[5])
    ] = 5,
    max_detections: Annotated[
        int,
        Form(ge=1, le=MAX_DETECTIONS, description="a frame without u and v: at most this many objects found"),
    ] = 10,
    min_confidence: Annotated[
        float | None,
        Form(
            ge=0,
            le=1,
            allow_inf_nan=False,
            description="a frame without u and v: report the objects found with at least this confidence "
            "(default: those the model's open-set calibration accepts as registered objects)",
        ),
    ] = None,
    cam_K: Annotated[
        str | None,
        Form(
            description="instead of fx, fy, cx, cy: the camera matrix K as OpenCV and BOP write it, 9 numbers "
            "row by row (fx 0 cx 0 fy cy 0 0 1)",
            examples=["572.4 0 325.3 0 573.6 242.0 0 0 1"],
        ),
    ] = None,
    window_mm: Annotated[
        float | None,
        Form(
            gt=0,
            le=10_000,
            allow_inf_nan=False,
            description="a patch: the side of the metric window it spans at the object's distance, mm "
            "(default: the model's, 200). Each object is registered with a window that follows its size "
            "(`window_mm` in GET /objects); a patch is compared with the objects of its window only, and "
            "refused when none has it",
        ),
    ] = None,
    dist_coeffs: Annotated[
        str | None,
        Form(
            description="OpenCV's distortion coefficients of the frame (k1 k2 p1 p2 [k3 [k4 k5 k6 ...]]): the "
            "frame is undistorted first (onto the same K), u and v with it; every pixel of the answer is of "
            "the undistorted frame",
        ),
    ] = None,
) -> RecognizeForm:
    """The form of `/recognize`, a dependency of each route that takes it (`KnownFieldsDep` reads its
    fields through it). Async, though it awaits nothing: so FastAPI calls it on the event loop, not on its
    thread pool (`service.deps.get_state`)."""
    if cam_K is not None:
        if any(x is not None for x in (fx, fy, cx, cy)):
            raise ApiError(422, "send the camera once: cam_K, or fx, fy, cx and cy")
        fx, fy, cx, cy = intrinsics(cam_K)
    if window_mm is not None and any(x is not None for x in (fx, fy, cx, cy)):
        raise ApiError(
            422,
            "window_mm is a patch's: a frame sent with its camera is cut through each registered object's "
            "window by the service; leave window_mm out",
        )
    dist = None if dist_coeffs is None else coefficients(dist_coeffs)
    if dist is not None and None not in (fx, fy, cx, cy) and u is not None and v is not None:
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        u, v = undistorted_point(u, v, K, dist)
    fields = Query(
        None,
        None,
        depth_scale,
        fx,
        fy,
        cx,
        cy,
        u,
        v,
        distance_mm,
        k,
        max_detections,
        min_confidence,
        dist=dist,
        window_mm=window_mm,
    )
    return RecognizeForm(rgb, depth, fields)


RecognizeFormDep = Annotated[RecognizeForm, Depends(recognize_form)]


@router.post(
    "/recognize",
    response_model=RecognizeOut,
    summary="Which registered objects an image shows and how each sits: a patch, the object at (u, v) of a "
    "frame, or every object of a whole frame",
    description=(
        "Send `rgb` (PNG/JPEG) and/or `depth` (16-bit PNG, mm x `depth_scale`): the modality picks the "
        "model. Either a square patch already centred on the object and spanning a metric window (the "
        "model's, or `window_mm`: the objects of that window are searched), or a full frame with intrinsics "
        "`fx`, `fy`, `cx`, `cy` and the object's centre `u`, `v` (pixels, where the object's origin "
        "projects), or a whole frame with its intrinsics and no centre: every registered object found in it "
        "(`detections`). `distance_mm` is the distance from the camera "
        "centre to the object's origin along the ray through (u, v) (‖t‖ of a BOP pose); a colour-only "
        "frame needs it. With depth and no `distance_mm`, the service measures the surface at (u, v) and "
        "cuts the patch there; each answer then puts the origin behind that surface by its template's "
        "offset (how far the origin of that object lies behind the surface seen from that viewpoint). The answer holds `k` distinct (object, viewpoint) "
        "matches, best first (with depth, re-ordered by the depth each explains), each with its azimuth, elevation and estimated in-plane angle (roll, "
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
async def recognize(state: StateDep, form: RecognizeFormDep) -> RecognizeOut:
    async with state.recognition_gate:  # bounds the memory of decoded images; waiting ones stay spooled
        q = await form.query()
        return await asyncio.wrap_future(state.recognizer.submit(answer, state, q))


@router.post(
    "/recognize/draw",
    response_class=Response,
    summary="The answer drawn over the image: a PNG",
    description=(
        "Takes what `POST /recognize` takes, recognises the same way, and returns the image sent (a frame; "
        f"a patch upscaled to {PATCH_DRAW_PX} px; a depth-only query in grey) as a PNG with the best "
        "`draw_k` answers drawn at their poses: each object's silhouette tinted and outlined, its axes "
        "(x red, y green, z blue, half its diameter long, from its origin) and its name and confidence. "
        "When the best answer is rejected as no registered object, it is drawn grey and dashed, labelled "
        "`unknown?`."
    ),
    responses={
        200: {"content": {"image/png": {}}, "description": "the image with the answers drawn"},
        **responses(400, 413, 422),
    },
    dependencies=[KnownFieldsDep],
)
async def recognize_draw(
    state: StateDep,
    form: RecognizeFormDep,
    draw_k: Annotated[
        int, Form(ge=1, description="how many of the answers to draw, best first (at most k)", examples=[1])
    ] = 1,
) -> Response:
    if draw_k > form.fields.k:
        raise ApiError(422, f"draw_k: at most k ({form.fields.k}) answers can be drawn, got {draw_k}")
    async with state.recognition_gate:
        q = await form.query()
        png = await asyncio.wrap_future(state.recognizer.submit(drawing, state, q, draw_k))
    return Response(png, media_type="image/png")
