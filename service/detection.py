"""Every registered object in a whole frame: what `POST /recognize` answers for a frame sent with its
intrinsics and no centre.

Proposals first (`service.proposals`: where an object may be and how large it looks, from the colour by
the objectness network, from depth by segmenting what stands on the support), then the verifier on each:
the model's whole pipeline (`service.pipeline`) cut at the proposal's centre and distance, which names the
object, gives its pose and the open-set verdict. A verified answer's box is its mesh projected at its
pose; answers whose boxes overlap a more confident one are the same object found twice (non-maximum
suppression); what the open-set verdict rejects is not one of the registered objects and is not
reported (unless `min_confidence` says otherwise)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from index.draw import project
from index.store import Snapshot
from index.windows import window_classes
from service.errors import ApiError
from service.pipeline.answer import Result
from service.pipeline.query import Decoded, Query, decode
from service.proposals import Proposal, propose
from service.state import AppState

#: boxes overlapping by more than this (intersection over union) are one object found twice: the more
#: confident stays. 0.5 is the detection's own criterion (`posedesc evaluate --protocol detect`): two
#: boxes that would both count as the same instance cannot both be right.
NMS_IOU = 0.5


@dataclass(frozen=True)
class Detection:
    """One object found: where its origin projects (`u`, `v`, px: where it was verified, or where the pose
    fit moved it), its extent (`box`: x0, y0, x1, y1 px,
    the mesh at the answered pose, clipped to the frame), the best answer's `confidence`, the verifier's
    whole answer at (u, v) (`result`: its matches, their confidences and poses) and the proposal it came
    from."""

    u: float
    v: float
    box: tuple[float, float, float, float]
    confidence: float
    result: Result
    proposal: Proposal


@dataclass(frozen=True)
class Found:
    """The detections, most confident first, the milliseconds each step took, how many proposals were
    verified and the model that verified them."""

    detections: tuple[Detection, ...]
    timings_ms: dict[str, float]
    proposals: int
    model: str


def detect(state: AppState, q: Query) -> Found:
    """The registered objects in the frame of `q` (a frame with fx, fy, cx, cy and no u, v): at most
    `q.max_detections`, each with a confidence of at least `q.min_confidence` (None: `_reported`)."""
    t0 = time.perf_counter()
    check(q)
    d = decode(state, q)
    return detect_decoded(state, q, d, time.perf_counter() - t0)


def check(q: Query) -> None:
    """Refuses, with what is missing, a frame query that cannot be searched whole."""
    missing = [f for f in ("fx", "fy", "cx", "cy") if getattr(q, f) is None]
    if missing:
        raise ApiError(
            422, f"a frame needs fx, fy, cx and cy to find objects in it; missing: {', '.join(missing)}"
        )
    if q.distance_mm is not None:
        raise ApiError(422, "distance_mm is the distance of the object at (u, v): send u and v with it")


def detect_decoded(state: AppState, q: Query, d: Decoded, decode_s: float = 0.0) -> Found:
    """`detect` after decoding (`service.pipeline.query.decode`): the proposals, each verified, the boxes
    suppressed and the floor applied. `decode_s`: the seconds decoding took, reported and counted in total."""
    t0 = time.perf_counter()
    ms: dict[str, float] = {"decode": decode_s}
    K = q.camera
    assert K is not None  # `check` refused a frame without its camera
    snapshot = state.store.snapshot  # every proposal verified against the same store
    windows = window_classes(snapshot.objects, d.embedder.info.window_mm)
    cfg = state.settings
    proposals = propose(
        d, K, state.colour_proposals, windows, cfg.detect_proposals, cfg.detect_depth_proposals
    )
    # a colour detection's confidence is at most its proposal's score (`confidence`): one under the floor
    # is not verified, as it could not be reported
    floor = cfg.detect_floor if q.min_confidence is None else q.min_confidence
    proposals = [p for p in proposals if p.source != "colour" or p.score >= floor]
    ms["propose"] = time.perf_counter() - t0
    t = time.perf_counter()
    found = [det for p in proposals if (det := _verify(state, snapshot, q, d, p, K)) is not None]
    ms["verify"] = time.perf_counter() - t
    kept = suppress(sorted(found, key=lambda x: -x.confidence))
    shown = [x for x in kept if reported(x, q.min_confidence, state.settings.detect_floor)]
    ms["total"] = time.perf_counter() - t0 + decode_s
    return Found(
        tuple(shown[: q.max_detections]),
        {k: round(v * 1000, 2) for k, v in ms.items()},
        len(proposals),
        d.embedder.path.stem,
    )


def _verify(
    state: AppState, snapshot: Snapshot, q: Query, d: Decoded, p: Proposal, K: np.ndarray
) -> Detection | None:
    """The verifier's answer at a proposal: screened at its shifts (`_centred`), then the whole pipeline
    cut at the best of them; None when nothing there can be answered."""
    w, h = d.size
    seen = snapshot if p.objects is None else snapshot.within(p.objects)
    at = _centred(state, seen, q, d, p)
    if at is None:
        return None
    try:
        result = state.pipelines[d.modality](at, d, seen)
    except ApiError:  # nothing measurable there (an empty depth patch): not an object
        return None
    if not result.matches:
        return None
    best = result.matches[0]
    mesh = state.draw_meshes.get(best.object_id)
    R, t = result.pose(0)
    box = _box(mesh.vertices if mesh is not None else None, R, t, K, (w, h), p)
    assert at.u is not None and at.v is not None  # `_centred` gives a centre
    u, v = (at.u, at.v) if result.fitted(0) is None else tuple(float(x) for x in (K @ t)[:2] / t[2])
    return Detection(u, v, box, confidence(result, p), result, p)


def confidence(result: Result, p: Proposal) -> float:
    """A detection's confidence: the verifier's in its best answer, times the objectness network's score
    for a colour proposal. Measured on the validation frames (docs/experiments.md), the verifier's
    confidence alone ranks a proposal that it screened at nine places too high: the ranking by the
    product had AP50 0.70 against 0.54 by the verifier's and 0.67 by the network's."""
    verified = float(result.confidences[0] or 0.0)
    return verified * p.score if p.source == "colour" else verified


def reported(x: Detection, min_confidence: float | None, colour_floor: float) -> bool:
    """Whether a detection is reported: its confidence at least `min_confidence` when given; else, from a
    colour proposal, at least `colour_floor` (`Settings.detect_floor`), and from depth, accepted by the
    model's open-set verdict (the verdict alone accepted nearly every colour proposal: ten a frame where
    no registered object was)."""
    if min_confidence is not None:
        return x.confidence >= min_confidence
    if x.proposal.source == "colour":
        return x.confidence >= colour_floor
    return x.result.reason is None


def _centred(state: AppState, snapshot: Snapshot, q: Query, d: Decoded, p: Proposal) -> Query | None:
    """Where around the proposal the screening pipeline (`AppState.screens`) is most confident: a 3 x 3
    grid of centres `Settings.detect_shift` of its window's side apart around the proposal's (and, for
    `detect_grids` > 1, grids of half the step around the best), then (a colour proposal) its distance
    nearer and farther by `detect_scale`; at most `detect_screens` screenings. None when nothing there can
    be answered (outside the frame, no depth there)."""
    cfg = state.settings
    w, h = d.size
    side = p.box[2] - p.box[0]  # the proposal's window (colour) or the segment's extent (depth), px
    screen = state.screens[d.modality]
    seen: dict[tuple[float, float, float], tuple[float, float]] = {}

    def score(u: float, v: float, log_d: float | None) -> tuple[float, float] | None:
        key = (round(u, 1), round(v, 1), round(log_d, 4) if log_d is not None else 0.0)
        if key not in seen:
            if not (0 <= u < w and 0 <= v < h) or len(seen) >= cfg.detect_screens:
                return None
            distance = None if log_d is None else float(np.exp(log_d))
            try:
                r = screen(replace(q, u=u, v=v, distance_mm=distance, k=1), d, snapshot)
            except ApiError:  # no depth there
                seen[key] = (-1.0, 0.0)
            else:
                seen[key] = (
                    (float(r.confidences[0] or 0.0), -r.matches[0].distance) if r.matches else (-1.0, 0.0)
                )
        return seen[key]

    u, v = p.u, p.v
    log_d = None if p.distance_mm is None else float(np.log(p.distance_mm))
    best = score(u, v, log_d)
    if best is None:
        return None
    step = cfg.detect_shift * side
    for _ in range(cfg.detect_grids if step > 0 else 0):  # 3 x 3 around the best so far, each step halved
        grid = [(u + i * step, v + j * step) for i in (-1, 0, 1) for j in (-1, 0, 1) if i or j]
        for gu, gv in grid:
            s = score(gu, gv, log_d)
            if s is not None and s > best:
                best, cu, cv = s, gu, gv
                u, v = cu, cv
        step /= 2
    if log_d is not None and cfg.detect_scale > 1:  # then nearer and farther, at the centre found
        centre_log = log_d
        for dl in (np.log(cfg.detect_scale), -np.log(cfg.detect_scale)):
            s = score(u, v, centre_log + dl)
            if s is not None and s > best:
                best, log_d = s, centre_log + dl
    if best[0] < 0:
        return None
    distance = None if log_d is None else float(np.exp(log_d))
    return replace(q, u=u, v=v, distance_mm=distance, estimated=True)


def _box(
    vertices: np.ndarray | None,
    R: np.ndarray,
    t: np.ndarray,
    K: np.ndarray,
    size: tuple[int, int],
    p: Proposal,
) -> tuple[float, float, float, float]:
    """The mesh's extent at the pose in the frame (clipped to it); without a mesh, the proposal's."""
    w, h = size
    if vertices is not None:
        px, z = project(vertices, R, t, K)
        px = px[z > 0]
        if len(px):
            x0, y0 = px.min(axis=0)
            x1, y1 = px.max(axis=0)
            return (float(max(x0, 0)), float(max(y0, 0)), float(min(x1, w)), float(min(y1, h)))
    return p.box


def iou(a: Sequence[float], b: Sequence[float]) -> float:
    """Intersection over union of two boxes (x0, y0, x1, y1)."""
    ix = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def suppress(ordered: Sequence[Detection]) -> list[Detection]:
    """Non-maximum suppression: each detection (most confident first) kept unless its box overlaps a kept
    one by more than `NMS_IOU`."""
    kept: list[Detection] = []
    for x in ordered:
        if all(iou(x.box, k.box) <= NMS_IOU for k in kept):
            kept.append(x)
    return kept
