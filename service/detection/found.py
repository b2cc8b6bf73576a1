"""What a whole frame's detection hands through its stages (`Frame`, frozen: each stage hands on a new one):
the places to look (`Proposal`), the objects found (`Detection`), and the answer (`Found`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from index.store import Snapshot
from service.detection.depth_segments import Support
from service.pipeline.answer import Result
from service.pipeline.query import Decoded, Query

#: a `Proposal`'s source when it is a part of a depth segment larger than any registered object (a guess at
#: where one of several touching objects ends); "depth" for a whole segment, "colour" for the objectness's
DEPTH_PART = "depth part"


@dataclass(frozen=True)
class Proposal:
    """A place to verify: the centre (px), the distance to cut at (mm; None: measured from depth there),
    the box it was seen in (x0, y0, x1, y1 px), its score (higher: more object-like), its source, and the
    objects it is verified against (None: all; a colour proposal's distance holds for one window class)."""

    u: float
    v: float
    distance_mm: float | None
    box: tuple[float, float, float, float]
    score: float
    source: str
    objects: frozenset[int] | None = None


@dataclass(frozen=True)
class Detection:
    """One object found: where its origin projects (`u`, `v`, px: where it was verified, or where the pose
    fit moved it), its extent (`box`: x0, y0, x1, y1 px, the mesh at the answered pose, clipped to the
    frame), the best answer's `confidence`, the verifier's whole answer at (u, v) (`result`: its matches,
    their confidences and poses) and the proposal it came from."""

    u: float
    v: float
    box: tuple[float, float, float, float]
    confidence: float
    result: Result
    proposal: Proposal
    #: its silhouette at the answered pose as COCO's compressed RLE (`service.detection.mask`), once reported
    mask: dict[str, object] | None = None
    #: how far the frame's colours are from its object's at its pose (`service.detection.agree`, 0-2;
    #: None: not measured: no colour, or an object without colours)
    colour_distance: float | None = None


@dataclass(frozen=True)
class Frame:
    """One frame on its way through the detection: the query, its decoded images, its intrinsics `K`, the
    store's snapshot every proposal is verified against, the confidence a detection needs (`floor`), and
    what the stages so far made of it: the places to look, the plane the frame's objects stand on (`support`,
    from its depth; None without) and the objects found."""

    q: Query
    d: Decoded
    K: np.ndarray
    snapshot: Snapshot
    floor: float
    proposals: tuple[Proposal, ...] = ()
    support: Support | None = None
    detections: tuple[Detection, ...] = ()


@dataclass(frozen=True)
class Found:
    """The detections, most confident first, the milliseconds each step took, how many proposals were
    verified, the model that verified them, and what was not searched for (`warnings`; `searched` false:
    nothing was, as the frame can show none of the registered objects)."""

    detections: tuple[Detection, ...]
    timings_ms: dict[str, float]
    proposals: int
    model: str
    #: what the detection could not do and the user should know (`service.detection.unsearched`)
    warnings: tuple[str, ...] = ()
    searched: bool = True
