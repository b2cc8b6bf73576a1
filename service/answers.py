"""What a query gets back, made on a recognition thread (never the render thread): the JSON answer
(`answer`; shaped here alone: `result_out`, `matches_out`, `found_out`), the picture of it (`drawing`,
`picture`: the one place answers are drawn), or both from one decoding (`answer_and_drawing`, which
`posedesc recognize` writes)."""

from __future__ import annotations

import time
from dataclasses import replace

import cv2
import numpy as np

from index.draw import Drawn, draw_answers, grey_to_rgb, patch_view
from index.geometry.pose import pose_to_view
from service.detection import Found, check, detect, detect_decoded
from service.pipeline.answer import Result
from service.pipeline.query import Decoded, Query, decode
from service.recognition import answerable, recognise, recognise_decoded
from service.schemas import DetectionOut, MatchOut, RecognizeOut, RleMask, TemplateOut
from service.state import AppState


def answer(state: AppState, q: Query) -> RecognizeOut:
    """What `POST /recognize` answers, made on a recognition thread: the answer's poses and models too
    (~1 ms for k = 5), so the event loop goes on reading and sending other requests meanwhile."""
    if q.finds:
        return found_out(detect(state, q), q.camera)
    return result_out(recognise(state, q), q.camera)


def drawing(state: AppState, q: Query, draw_k: int) -> bytes:
    """The PNG `POST /recognize/draw` answers, made on a recognition thread (never the render thread): a
    frame without a centre with each object found drawn at its best answer."""
    return answer_and_drawing(state, q, draw_k)[1]


def answer_and_drawing(state: AppState, q: Query, draw_k: int) -> tuple[RecognizeOut, bytes]:
    """What `/recognize` and `/recognize/draw` answer to `q`, the query decoded and run once (`posedesc
    recognize` writes both)."""
    answerable(state)
    if q.finds:
        check(q)
    t0 = time.perf_counter()
    d = decode(state, q)
    decode_s = time.perf_counter() - t0
    if q.finds:
        found = detect_decoded(state, q, d, decode_s)
        return found_out(found, q.camera), picture(state, q, d, [(x.result, 1) for x in found.detections])
    result = recognise_decoded(state, q, d, decode_s)
    return result_out(result, q.camera), picture(state, q, d, [(result, draw_k)])


def picture(state: AppState, q: Query, d: Decoded, answers: list[tuple[Result, int]]) -> bytes:
    """The frame (or the patch, enlarged) as a PNG with the first n matches of each (result, n) drawn."""
    if d.rgb is not None:
        image = d.rgb
    else:
        assert d.depth is not None  # `decode` refuses a query without images
        image = grey_to_rgb(d.depth)
    K = q.camera
    if K is None:  # a patch: its answers are in the patch camera, at the distance it was cut at
        spec = d.embedder.info.spec
        spec = spec if q.window_mm is None else replace(spec, window_mm=q.window_mm)
        image, K = patch_view(image, spec, answers[0][0].distance_mm)
    state.forget_deleted()
    drawn = []
    for result, n in answers:
        for i, (m, c) in enumerate(zip(result.matches[:n], result.confidences[:n], strict=True)):
            mesh = state.draw_meshes.get(m.object_id)
            if mesh is not None:  # deleted since
                R, t = result.pose(i)
                drawn.append((mesh, Drawn(m.name, c, R, t, rejected=result.reason is not None)))
    ok, png = cv2.imencode(".png", cv2.cvtColor(draw_answers(image, drawn, K), cv2.COLOR_RGB2BGR))
    assert ok  # a uint8 RGB image always encodes
    return png.tobytes()


NOTHING_FOUND = "no registered object was found in the frame"
NOTHING_SEARCHED = "no registered object can be found in this frame: `warnings` says why"


def result_out(result: Result, K: np.ndarray | None) -> RecognizeOut:
    """The answer to a query with a centre, or to a patch."""
    matches = matches_out(result, K)
    return RecognizeOut(
        matches=matches,
        best=None if result.reason else matches[0],
        reason=result.reason,
        score=result.score,
        colour_distance=result.colour_distance,
        unexplained=None if result.unexplained is None else round(result.unexplained, 4),
        timings_ms=result.timings_ms,
        model=result.model,
    )


def matches_out(result: Result, K: np.ndarray | None) -> list[MatchOut]:
    """A result's matches as the API answers them, each with its confidence and pose: the fitted pose
    where the pose fit moved it (`Result.pose`), its angles read back along the ray through its origin
    (`index.geometry.pose.pose_to_view`), and where its origin projects in a frame of intrinsics `K`."""
    out = []
    for i, (m, c) in enumerate(zip(result.matches, result.confidences, strict=True)):
        R, t = result.pose(i)
        template = TemplateOut(azimuth=m.azimuth, elevation=m.elevation, inplane=m.inplane)
        angles = {}
        if refined := result.fitted(i) is not None:
            view = pose_to_view(R, t)
            angles = {"azimuth": view.azimuth, "elevation": view.elevation, "inplane": view.inplane}
        u = v = None
        if K is not None and t[2] > 0:
            u, v = (float(x) for x in (K @ t)[:2] / t[2])
        fields = {**m.__dict__, **angles}
        out.append(
            MatchOut(
                **fields,
                confidence=c,
                R=[float(x) for x in R.ravel()],
                t=[float(x) for x in t],
                refined=refined,
                template=template,
                u=u,
                v=v,
            )
        )
    return out


def found_out(found: Found, K: np.ndarray | None) -> RecognizeOut:
    """The answer to a frame without a centre: the detections, and the first one's answer at the top."""
    detections = []
    for x in found.detections:
        matches = matches_out(x.result, K)
        mask = RleMask.model_validate(x.mask) if x.mask is not None else None
        detections.append(
            DetectionOut(
                u=x.u,
                v=x.v,
                box=list(x.box),
                best=matches[0],
                matches=matches,
                confidence=round(x.confidence, 4),
                colour_distance=None if x.colour_distance is None else round(x.colour_distance, 4),
                mask=mask,
            )
        )
    first = detections[0] if detections else None
    return RecognizeOut(
        matches=first.matches if first else [],
        best=first.best if first else None,
        reason=None if first else NOTHING_FOUND if found.searched else NOTHING_SEARCHED,
        score=found.detections[0].result.score if found.detections else "local",
        timings_ms=found.timings_ms,
        model=found.model,
        detections=detections,
        warnings=list(found.warnings),
    )
