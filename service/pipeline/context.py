"""What one query carries through the pipeline (`Context`, frozen: each stage hands on a new one) and
what a stage is (`Stage`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from index.features.embed import Embedder
from index.store import Match, Snapshot

Key = tuple[int, float, float]  # `index.store.local_key`: object, azimuth, elevation
Pose = tuple[Key, float]  # a viewpoint and a roll (degrees, rounded to 3 decimals)


@dataclass(frozen=True)
class Query:
    """What a user sends. `distance_mm`: from the camera centre to the object's origin along the ray
    through (u, v) (‖t‖ of a BOP pose); without it, a frame's depth gives the surface's distance there."""

    rgb: bytes | None
    depth: bytes | None
    #: mm per depth unit; None: the file's own (mm for a 16-bit PNG, metres for float depth)
    depth_scale: float | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    u: float | None = None
    v: float | None = None
    distance_mm: float | None = None
    k: int = 5
    #: a frame without u and v: how many objects found are reported, and the confidence they need
    #: (None: the model's open-set verdict decides)
    max_detections: int = 10
    min_confidence: float | None = None
    #: u, v and distance_mm are the detection's estimates (`service.detection`), not what a user sent: the
    #: colour pose fit then lets the translation move as far as such estimates are off
    estimated: bool = False
    #: OpenCV's distortion coefficients of the frame (`service.inputs.camera`): its images are undistorted
    #: first, and u, v are already the undistorted frame's
    dist: tuple[float, ...] | None = None
    #: a patch: the metric side of the window it spans, mm (None: the model's); only the objects registered
    #: with that window are searched (`service.pipeline.classes`)
    window_mm: float | None = None

    @property
    def camera(self) -> np.ndarray | None:
        """The frame's intrinsics K (3, 3), or None when any of fx, fy, cx, cy was not sent (a patch, or a
        partial camera the checks refuse)."""
        if self.fx is None or self.fy is None or self.cx is None or self.cy is None:
            return None
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def finds(self) -> bool:
        """Whether this query asks to find the objects: a frame (intrinsics sent) without a centre."""
        camera = any(getattr(self, f) is not None for f in ("fx", "fy", "cx", "cy"))
        return camera and self.u is None and self.v is None


@dataclass(frozen=True)
class Decoded:
    """A query's images, decoded, and the model its modality picks."""

    modality: str
    embedder: Embedder
    rgb: np.ndarray | None
    depth: np.ndarray | None
    #: the mm per unit the depth was read with (the query's, or its file's own: `service.inputs.images`)
    depth_scale: float = 1.0

    @property
    def size(self) -> tuple[int, int]:
        """The images' width and height, px (`decode` checks both agree)."""
        image = self.rgb if self.rgb is not None else self.depth
        assert image is not None  # `decode` refuses a query without images
        return image.shape[1], image.shape[0]


@dataclass(frozen=True)
class Patches:
    """The query cut as the network takes it, once per turn. rgb (n, S, S, 3) uint8 or None; depth
    (n, S, S) mm or None; offsets (n,) degrees of roll undone; distance (mm) the window was cut at, along
    `ray` (3,), the unit ray through the centre in the query's camera (for a patch, the patch camera's)."""

    rgb: np.ndarray | None
    depth: np.ndarray | None
    offsets: np.ndarray
    distance: float
    ray: np.ndarray


class Scorer(Protocol):
    """The re-ranking's score of stored templates against this query (`service.pipeline.score.LocalScore`):
    `local`, the snapshot's local features by viewpoint."""

    @property
    def local(self) -> Mapping[Key, np.ndarray]: ...

    def pairs(self, poses: Sequence[Pose]) -> np.ndarray: ...

    def table(self, keys: Sequence[Key], rolls: Sequence[float]) -> np.ndarray: ...


@dataclass(frozen=True)
class Ranked:
    """The candidates the re-ranking scored: `have`, their places among the search's matches (those whose
    viewpoint has local features); `keys`, `rolls`, `scores` (N,) their poses and local scores as the
    stages so far left them; `first` their poses as the search gave them."""

    have: tuple[int, ...]
    keys: tuple[Key, ...]
    rolls: tuple[float, ...]
    scores: np.ndarray
    first: tuple[Pose, ...]


@dataclass(frozen=True)
class Context:
    """One query in the pipeline. `snapshot`: the store as the query found it, for all its stages.
    `patches`: the query cut at its turns (the depth as measured); `described`: those patches as the
    descriptor sees them (masked: `service.pipeline.mask`), `keep` (n, S, S) bool that mask or None;
    `matches`: the search's candidates; `ranked`: the local scores, once re-ranked; `scorer`: the
    re-ranking's score of this query (holding the query's cuts, made once per roll, and every pose it
    scored: the same template against the same cut of the query scores the same, so none is scored
    twice); `score`: what the answers' distances are ("local" once re-ranked); `wanted`: how many answers
    are ranked, k or more when the open-set verdict reads past the best (`service.rejection.LISTED`);
    `window_mm`: the window the query is cut through, its objects' class's (`index.templates.windows`; None: the
    model's), `snapshot` then seeing that class's objects only when the store holds several."""

    query: Query
    decoded: Decoded
    snapshot: Snapshot
    patches: Patches | None = None
    described: Patches | None = None
    keep: np.ndarray | None = None
    descriptors: np.ndarray | None = None
    matches: Sequence[Match] = ()
    ranked: Ranked | None = None
    scorer: Scorer | None = None
    score: str = "descriptor"
    wanted: int = 0
    window_mm: float | None = None

    @property
    def window(self) -> float:
        """The window the query is cut through (mm): `window_mm`, or the model's."""
        return self.decoded.embedder.info.window_mm if self.window_mm is None else self.window_mm


class Stage(Protocol):
    """One step of the pipeline: `name` is its entry in `timings_ms`; a call returns the context handed
    on, or None when the stage has nothing to do for this query (no entry then)."""

    name: str

    def __call__(self, ctx: Context) -> Context | None: ...
