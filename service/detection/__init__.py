"""Every registered object in a whole frame: what `POST /recognize` answers for a frame sent with its
intrinsics and no centre, and what `posedesc evaluate --protocol detect` and `posedesc bench --only detect`
measure (they call `detect` as the route does).

The stages, in order (`stages`), each a module of this package with one call on the frame's frozen
`found.Frame` and one frozen config built from the settings:

- `propose` (`proposals.Propose`): where an object may be: from the colour, the objectness network; from
  depth, the segments standing on the support (`depth_segments`);
- `verify` (`verify.Verify`): each place recognised by the model's whole pipeline (a depth segment's after
  a screening around its centre), which names the object, gives its pose, its box and the open-set verdict;
- `agree` (`agree.Agree`): how far the frame's colours are from the object's at its pose, which tells a
  registered object from one nobody registered: a colour frame's confidences weighed by it, a frame with
  depth held to a ceiling on it (`report.floors`);
- `stand` (`stand.Stand`): with depth, a detection whose pose puts its object through the table the frame's
  objects stand on is dropped;
- `merge` (`merge.Merge`): one instance found twice (boxes overlapping) reported once, the more confident;
- `report` (`report.Report`): the confidence a detection needs (`report.confidence`, `report.reported`) and
  at most `max_detections`;
- `mask` (`mask.Silhouettes`): each reported object's silhouette at its pose, as COCO's RLE.

`timings_ms`: `decode`, then each stage by its name, and `total`. Adding a stage is a new module and one
line in `stages`."""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Protocol

from index.templates.windows import window_classes
from service.detection.agree import Agree
from service.detection.found import Detection, Found, Frame, Proposal
from service.detection.mask import Silhouettes
from service.detection.merge import Merge
from service.detection.proposals import Propose
from service.detection.report import Report, floors, reported
from service.detection.stand import Stand
from service.detection.verify import Verify
from service.errors import ApiError
from service.inputs.depth_units import check_scene_depth
from service.pipeline.query import COLOUR_SHAPE_ONLY, Decoded, Query, by_model, decode
from service.recognition import answerable
from service.state import AppState

__all__ = [
    "Detection",
    "Found",
    "Proposal",
    "check",
    "detect",
    "detect_decoded",
    "floors",
    "reported",
    "stages",
    "unsearched",
]


class FrameStage(Protocol):
    """One step of the detection: a frame in, the frame with the step's work done out."""

    @property
    def name(self) -> str: ...

    def __call__(self, frame: Frame) -> Frame: ...


def stages(state: AppState) -> tuple[FrameStage, ...]:
    """The detection's stages at the state's settings, in order."""
    s = state.settings
    return (
        Propose.build(s, state.colour_proposals),
        Verify.build(state),
        Agree.build(state),
        Stand.build(state),
        Merge.build(s),
        Report.build(s),
        Silhouettes.build(state),
    )


#: the stages run on each part of the store apart (`by_model`): propose, verify, agree, stand
STAGES_APART = 4


def detect(state: AppState, q: Query) -> Found:
    """The registered objects in the frame of `q` (a frame with fx, fy, cx, cy and no u, v): at most
    `q.max_detections`, each with a confidence of at least `q.min_confidence` (None: `report.reported`)."""
    answerable(state)
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
    """`detect` after decoding (`service.pipeline.query.decode`): the stages in order on one store snapshot
    (every proposal verified against the same objects). `decode_s`: the seconds decoding took, reported and
    counted in total."""
    t0 = time.perf_counter()
    K = q.camera
    assert K is not None  # `check` refused a frame without its camera
    if d.depth is not None:  # in other units than it says, depth would find nothing: refused, saying so
        model = d.embedder.info.window_mm
        windows = sorted(window_classes(state.store.snapshot.objects, model), key=lambda w: w != model)
        focal = (K[0, 0] + K[1, 1]) / 2
        check_scene_depth(d.depth, focal, windows or [model], d.embedder.info.spec.size, d.depth_scale)
    at = floors(state.settings, d.depth is not None)
    floor = at.confidence if q.min_confidence is None else q.min_confidence
    ms: dict[str, float] = {"decode": decode_s}
    steps = stages(state)
    # each part of the store found by its own model, up to `stand`; then merged and reported together
    frames = [Frame(q, dp, K, snap, floor) for dp, snap in by_model(state, d)]
    warnings = unsearched(state, frames)
    if not frames:  # nothing the frame can show is registered (`unsearched` says why)
        ms["total"] = time.perf_counter() - t0 + decode_s
        ms_out = {k: round(v * 1000, 2) for k, v in ms.items()}
        return Found((), ms_out, 0, d.embedder.path.stem, warnings, searched=False)
    for stage in steps[:STAGES_APART]:
        t = time.perf_counter()
        frames = [stage(fr) for fr in frames]
        ms[stage.name] = time.perf_counter() - t
    proposals = max(len(fr.proposals) for fr in frames)
    frame = replace(frames[0], detections=tuple(x for fr in frames for x in fr.detections))
    for stage in steps[STAGES_APART:]:
        t = time.perf_counter()
        frame = stage(frame)
        ms[stage.name] = time.perf_counter() - t
    ms["total"] = time.perf_counter() - t0 + decode_s
    return Found(
        frame.detections,
        {k: round(v * 1000, 2) for k, v in ms.items()},
        proposals,
        d.embedder.path.stem,
        warnings,
    )


#: at most this many names in a warning; the rest counted
NAMED = 5


def unsearched(state: AppState, frames: list[Frame]) -> tuple[str, ...]:
    """What the frame's parts (`by_model`) leave out of the store, said: the shape-only objects a colour
    frame does not search for (`COLOUR_SHAPE_ONLY`)."""
    objects = state.store.snapshot.objects
    searched = {oid for fr in frames for oid in fr.snapshot.objects}
    left = sorted(rec.name for oid, rec in objects.items() if oid not in searched)
    if not left:
        return ()
    names = ", ".join(left[:NAMED]) + (f" and {len(left) - NAMED} more" if len(left) > NAMED else "")
    return (COLOUR_SHAPE_ONLY.format(names=names),)
