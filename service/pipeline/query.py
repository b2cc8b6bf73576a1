"""The query and its cut: what a user sends (`Query`), its checks and decoding (`decode`), and the patches
the network takes (`cut`: from a full frame and the object's centre, or from a patch already centred on
it), at any roll (a roll undone: the object upright). The pipeline's first stage (`Cut`) cuts the query
once per turn (`query_turns`); the re-ranking cuts it again at the rolls its candidates give
(`service.pipeline.score.QueryCuts`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import cv2
import numpy as np

from index.features.embed import Embedder
from index.features.patches import PatchSpec, crops, patch_camera
from index.store import ObjectRecord, Snapshot, TemplateStore
from index.templates.register import TEXTURED_KEY, TemplateConfig
from service.errors import ApiError, NothingMeasured
from service.inputs.camera import undistorted
from service.inputs.depth_units import check_frame_distance, check_given_distance, check_patch_distance
from service.inputs.images import read_depth, read_rgb
from service.pipeline.context import Context, Decoded, Patches, Query
from service.settings import Settings

#: depth stored in whole metres rounds to 0 for anything nearer than half a metre: the empty-depth errors
#: say what the service reads, the commonest cause of an empty depth where an object is
UNITS_HINT = " (a 16-bit PNG is read in mm times depth_scale: whole metres round to 0)"

FRAME_FIELDS = ("fx", "fy", "cx", "cy", "u", "v")
MIN_DISTANCE_MM, MAX_DISTANCE_MM = 1.0, 100_000.0  # the object's distance, given or measured
#: a distance sent below this is no object's in mm (the smallest registered, 20 mm, is seen from farther)
PLAUSIBLE_DISTANCE_MM = 10.0


class Loaded(Protocol):
    """What `decode` reads of the service's state (`service.state.AppState`, which builds this package's
    pipelines: typed by its shape, not imported)."""

    @property
    def settings(self) -> Settings: ...

    @property
    def embedders(self) -> Mapping[str, Embedder]: ...

    @property
    def store(self) -> TemplateStore: ...


#: what a whole colour frame says of the shape-only objects it does not search for (`by_model`). On YCB-V's
#: real colour frames of 12 shape-only meshes (three videos, 260 instances) the colour detection found none
#: and named 31 false ones (`docs/results/ycbv-detect-rgb-{0,1,2}.json`; docs/experiments.md, "Shape-only
#: objects in a whole colour frame")
COLOUR_SHAPE_ONLY = (
    "not searched for in a whole colour frame, as their meshes have no colours: {names}. Colour alone cannot "
    "tell them from what stands around; send the frame with depth, or the object's centre (u, v)"
)


def untextured(rec: ObjectRecord) -> bool:
    """Whether an object is shape-only: its mesh without colours (`TEXTURED_KEY` false; objects registered
    before the flag was kept count as textured)."""
    return rec.extra.get(TEXTURED_KEY) is False


def shape_only(store: TemplateStore) -> bool:
    """Whether every registered object is shape-only (`untextured`): then the colour of an RGB-D frame can
    match nothing but grey renders, and the depth model answers."""
    objects = store.snapshot.objects.values()
    return bool(objects) and all(untextured(rec) for rec in objects)


def by_model(state: Loaded, d: Decoded) -> list[tuple[Decoded, Snapshot]]:
    """The frame's images and the part of the store each model searches: the whole store with the model of
    the frame's modality; but an RGB-D frame of a store holding shape-only and textured objects has its
    shape-only ones found by the depth model, as when every object is shape-only (`decode`): the colour of
    a grey render matches no real surface, and adding colour to a frame must never lose what its depth
    alone finds. Costs a second pass (its proposals verified twice) for such stores only. A colour frame
    has no part for shape-only objects, and none at all when every object is shape-only
    (`COLOUR_SHAPE_ONLY`). An RGB-D frame with its camera and a centre is split alike, and answered by the
    part whose best answer shows the most (`service.recognition.recognise_decoded`)."""
    snapshot = state.store.snapshot
    bare = frozenset(oid for oid, rec in snapshot.objects.items() if untextured(rec))
    if d.modality == "rgb" and bare:  # colour alone: no part for shape-only objects (`COLOUR_SHAPE_ONLY`)
        textured = frozenset(snapshot.objects) - bare
        return [(d, snapshot.within(textured))] if textured else []
    depth = state.embedders.get("depth")
    if d.modality != "rgbd" or depth is None:
        return [(d, snapshot)]
    if not bare or len(bare) == len(snapshot.objects):
        return [(d, snapshot)]
    textured = frozenset(snapshot.objects) - bare
    return [
        (d, snapshot.within(textured)),
        (replace(d, modality="depth", embedder=depth), snapshot.within(bare)),
    ]


def decode(state: Loaded, q: Query) -> Decoded:
    """Checks what was sent, picks the model of its modality (an RGB-D frame: the depth model when every
    registered object is shape-only, `shape_only`) and decodes the images."""
    embedders, settings = state.embedders, state.settings
    if q.k > settings.max_k:
        raise ApiError(422, f"k: must be at most {settings.max_k}, got {q.k}")
    if q.rgb is None and q.depth is None:
        raise ApiError(422, "send an `rgb` image, a `depth` image, or both")
    modality = (
        "rgbd" if q.rgb is not None and q.depth is not None else "rgb" if q.rgb is not None else "depth"
    )
    if modality == "rgbd" and "depth" in embedders and shape_only(state.store):
        modality = "depth"  # the colour still decoded: drawn on, and checked against the depth's size
    embedder = embedders.get(modality)
    if embedder is None:
        loaded = ", ".join(sorted(embedders))
        raise ApiError(422, f"no {modality} model is loaded (loaded: {loaded}); send what one of them takes")
    px = settings.max_image_pixels
    rgb = None if q.rgb is None else read_rgb(q.rgb, px)
    depth, scale = (None, 1.0) if q.depth is None else read_depth(q.depth, q.depth_scale, px)
    if rgb is not None and depth is not None and rgb.shape[:2] != depth.shape:
        raise ApiError(
            422,
            f"rgb is {rgb.shape[1]} x {rgb.shape[0]} px but depth is {depth.shape[1]} x {depth.shape[0]} px",
        )
    h, w = (rgb if rgb is not None else depth).shape[:2]  # type: ignore[union-attr]
    check_camera(q, w, h)
    if q.dist is not None:
        K = q.camera
        if K is None:
            raise ApiError(
                422, "dist_coeffs: distortion is of a frame's camera: send its cam_K (or fx, fy, cx, cy)"
            )
        rgb, depth = undistorted(rgb, depth, K, q.dist)
    return Decoded(modality, embedder, rgb, depth, scale)


def check_camera(q: Query, width: int, height: int) -> None:
    """Refuses what no camera sends: a principal point far off the frame (it lies near the image's centre;
    a crop may move it, by less than a frame), and a distance that reads as metres sent as millimetres."""
    for name, c, side in (("cx", q.cx, width), ("cy", q.cy, height)):
        if c is not None and not -side <= c <= 2 * side:
            raise ApiError(
                422,
                f"{name} = {c:g} px lies far off the {width} x {height} px frame: the principal point is near "
                f"the image's centre (about {side / 2:g} px here); check the camera's intrinsics "
                "(fx, fy, cx, cy in px, as OpenCV's camera matrix K holds them)",
            )
    if q.distance_mm is not None and q.distance_mm < PLAUSIBLE_DISTANCE_MM:
        hint = (
            f"; {q.distance_mm:g} reads as metres: send distance_mm={q.distance_mm * 1000:g}"
            if q.distance_mm * 1000 <= MAX_DISTANCE_MM
            else ""
        )
        raise ApiError(
            422,
            f"distance_mm = {q.distance_mm:g}: the object's distance in millimetres, from the camera centre to "
            f"its origin, is at least {PLAUSIBLE_DISTANCE_MM:g} mm{hint}",
        )


@dataclass(frozen=True)
class CutConfig:
    """`offsets`: the query's turns, degrees (`turn_offsets` of `query_turns` and the templates' in-plane
    spacing); `patch_distance_mm`: the distance of a patch sent without one (`Settings.patch_distance_mm`)."""

    spec: PatchSpec
    offsets: tuple[float, ...]
    patch_distance_mm: float

    @classmethod
    def from_settings(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> CutConfig:
        spacing = templates.inplane_spacing(embedder.info.inplane_step)
        offsets = turn_offsets(settings.query_turns, spacing)
        return cls(embedder.info.spec, tuple(float(o) for o in offsets), settings.patch_distance_mm)


@dataclass(frozen=True)
class Cut:
    """The query cut once per turn (`CutConfig.offsets`): the patches every later stage starts from."""

    name = "cut"

    config: CutConfig

    @classmethod
    def build(cls, settings: Settings, embedder: Embedder, templates: TemplateConfig) -> Cut:
        return cls(CutConfig.from_settings(settings, embedder, templates))

    def __call__(self, ctx: Context) -> Context:
        c, d = self.config, ctx.decoded
        spec = c.spec if ctx.window_mm is None else replace(c.spec, window_mm=ctx.window_mm)
        q = replace(ctx.query, depth_scale=d.depth_scale)  # the unit checks name the scale read with
        # a patch of another window stands as far as its templates were rendered: scaled with the window
        far = c.patch_distance_mm * spec.window_mm / c.spec.window_mm
        p = cut(q, d.rgb, d.depth, spec, c.offsets, patch_distance_mm=far)
        return replace(ctx, patches=p, described=p)


def turn_offsets(turns: int, spacing: float) -> np.ndarray:
    """The query's turns, degrees: j * spacing / turns (j < turns); the whole turn when spacing is 0."""
    span = spacing if spacing > 0 else 360.0
    return np.arange(max(1, turns)) * (span / max(1, turns))


def cut(
    q: Query,
    rgb: np.ndarray | None,
    depth: np.ndarray | None,
    spec: PatchSpec,
    offsets: Sequence[float] | np.ndarray = (0.0,),
    *,
    patch_distance_mm: float,
) -> Patches:
    """The patches of a decoded query, one per turn in `offsets` (degrees of roll undone).
    `patch_distance_mm`: how far a patch sent without a distance (and without depth at its centre) is."""
    given = [f for f in FRAME_FIELDS if getattr(q, f) is not None]
    if given and len(given) < len(FRAME_FIELDS):
        missing = ", ".join(f for f in FRAME_FIELDS if f not in given)
        raise ApiError(422, f"a full frame needs fx, fy, cx, cy, u and v; missing: {missing}")
    if given:
        K, centre, distance = _from_frame(q, rgb, depth, spec)
    else:
        rgb, depth, distance = _from_patch(q, rgb, depth, spec, patch_distance_mm)
        K, centre = patch_camera(spec, distance), ((spec.size - 1) / 2, (spec.size - 1) / 2)
    offsets = np.asarray(offsets, float)
    if given or offsets.any():
        rgbs, depths = crops(rgb, depth, K, centre, distance, spec, offsets)
    else:  # a patch, unturned (the usual query): no warp at all
        rgbs = None if rgb is None else np.empty((len(offsets), *rgb.shape), np.uint8)
        depths = None if depth is None else np.empty((len(offsets), *depth.shape), np.float32)
    if not given:  # a patch where it is not turned: the patch itself, no resampling
        unturned = offsets == 0
        if rgbs is not None and rgb is not None:
            rgbs[unturned] = rgb
        if depths is not None and depth is not None:
            depths[unturned] = depth
    if depths is not None and not (depths[0] > 0).any():
        raise NothingMeasured(
            f"the depth patch is all zero: no depth was measured around the object{UNITS_HINT}"
        )
    if depths is not None and q.distance_mm is not None:  # a measured distance agrees by construction
        s = spec.size
        centre_quarter = depths[0][3 * s // 8 : 5 * s // 8, 3 * s // 8 : 5 * s // 8]
        check_given_distance(centre_quarter[centre_quarter > 0], distance, spec.window_mm, _scale(q))
    return Patches(
        rgbs,
        depths,
        offsets,
        distance,
        _unit(np.linalg.inv(K) @ np.array([centre[0], centre[1], 1.0])),
    )


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _from_frame(q: Query, rgb, depth, spec: PatchSpec) -> tuple[np.ndarray, tuple[float, float], float]:
    h, w = (rgb if rgb is not None else depth).shape[:2]
    assert q.u is not None and q.v is not None  # a frame query has them all (checked by the caller)
    u, v = float(q.u), float(q.v)
    if not (0 <= u < w and 0 <= v < h):
        raise ApiError(422, f"the centre (u, v) = ({u:g}, {v:g}) is outside the {w} x {h} frame")
    K = q.camera
    assert K is not None  # as u and v
    distance = q.distance_mm
    if distance is None:
        if depth is None:
            raise ApiError(
                422, "a colour-only frame needs distance_mm (from the camera to the object's origin, mm)"
            )
        distance = _measured(_depth_at(depth, K, u, v))
        check_frame_distance(distance, (K[0, 0] + K[1, 1]) / 2, spec.window_mm, spec.size, _scale(q))
    return K, (u, v), distance


def _depth_at(depth: np.ndarray, K: np.ndarray, u: float, v: float, r: int = 7) -> float:
    """Distance (mm, along the ray) of the surface at (u, v): median of the valid depths around it."""
    iu, iv = int(u), int(v)
    win = depth[max(0, iv - r) : iv + r + 1, max(0, iu - r) : iu + r + 1]
    valid = win[win > 0]
    if valid.size == 0:
        raise NothingMeasured(f"no depth around the centre ({u:g}, {v:g}){UNITS_HINT}; or send distance_mm")
    ray = np.linalg.inv(K) @ np.array([u, v, 1.0])
    return float(np.median(valid) * np.linalg.norm(ray))


def _from_patch(q: Query, rgb, depth, spec: PatchSpec, default_mm: float):
    """A patch already centred on the object, spanning the model's metric window: resized to the input."""
    size = spec.size
    h, w = (rgb if rgb is not None else depth).shape[:2]
    if abs(h - w) > 1:
        raise ApiError(
            422,
            f"a patch must be square ({w} x {h} px); a full frame needs its camera, fx, fy, cx and cy (with u "
            "and v for the object there; without them every registered object in it is found)",
        )
    rgb_p = None if rgb is None else cv2.resize(rgb, (size, size), interpolation=cv2.INTER_AREA)
    depth_p = None if depth is None else cv2.resize(depth, (size, size), interpolation=cv2.INTER_NEAREST)
    distance = q.distance_mm
    if distance is None and depth_p is not None:
        c = depth_p[size * 3 // 8 : size * 5 // 8, size * 3 // 8 : size * 5 // 8]
        distance = _measured(float(np.median(c[c > 0]))) if (c > 0).any() else None
        if distance is not None:
            check_patch_distance(distance, spec.window_mm, _scale(q))
    return rgb_p, depth_p, distance or default_mm


def _scale(q: Query) -> float:
    """The mm per depth unit the query's depth was read with (the pipeline's cut sets it from `Decoded`)."""
    return 1.0 if q.depth_scale is None else q.depth_scale


def _measured(distance: float) -> float:
    if not MIN_DISTANCE_MM <= distance <= MAX_DISTANCE_MM:
        raise NothingMeasured(
            f"the depth at the centre says {distance:.3g} mm, outside {MIN_DISTANCE_MM:g} to "
            f"{MAX_DISTANCE_MM:g} mm: is depth_scale right?",
        )
    return distance
