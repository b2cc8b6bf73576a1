"""One recognition: decoded images -> the model's patch (and its turns) -> descriptors -> k distinct answers.

Runs in a worker thread (never on the event loop) and never waits on a registration: it reads the
store's current snapshot and runs the model's own onnxruntime session. `posedesc evaluate --protocol
service` calls `recognise` itself, so what it measures is what a user of `POST /recognize` gets;
`posedesc bench` times `recognise_decoded`, the part after decoding that `recognise` calls.

Roll: a template's in-plane angle is a roll the service can answer, so with templates over the whole
turn (a model trained with roll, or the settings) every answer's in-plane is an estimate. With
`query_turns` n > 1 the query is also cut turned by j * s / n (j < n, s the templates' in-plane step, or
the whole turn when they are upright only): the n patches are embedded in one batch and searched, and a
match of template in-plane θ on the turn by o says the object is rolled θ + o (`crop` undoes o)."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from index.embed import Embedder
from index.local import (
    cell_cosines,
    cell_cosines_across,
    cell_weights,
    l2,
    masked_distance,
    masked_distance_across,
    relief,
    relief_distance,
    relief_distance_across,
    split_stored,
)
from index.patches import PatchSpec, batch_inputs, crops, fill_depth, patch_camera, turn_masks
from index.pose import wrap_degrees
from index.store import Match, Snapshot, local_key
from service.depth_units import check_frame_distance, check_given_distance, check_patch_distance
from service.errors import ApiError
from service.images import read_depth, read_rgb
from service.origin import origin_distances
from service.refine import TABLES, Key
from service.rejection import LISTED, judge, read_calibrations
from service.state import AppState

FRAME_FIELDS = ("fx", "fy", "cx", "cy", "u", "v")
MAX_PX = 1e6  # focal lengths and image coordinates beyond this are no camera's
MIN_DISTANCE_MM, MAX_DISTANCE_MM = 1.0, 100_000.0  # the object's distance, given or measured


@dataclass(frozen=True)
class Query:
    """What a user sends. `distance_mm`: from the camera centre to the object's origin along the ray
    through (u, v) (‖t‖ of a BOP pose); without it, a frame's depth gives the surface's distance there."""

    rgb: bytes | None
    depth: bytes | None
    depth_scale: float = 1.0
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    u: float | None = None
    v: float | None = None
    distance_mm: float | None = None
    k: int = 5


@dataclass
class Result:
    """The answers, and where they are: `ray` (3,) the unit ray through the object's centre in the query's
    camera (the patch camera for a patch: the optical axis), `distance_mm` how far along it the query was
    cut. With a match's view they give its pose (`service.poses`). `score`: what each match's distance
    is ("local" when re-ranked, else "descriptor"); `confidences` per match and `reason` (the best answer
    rejected, or None) from `service.rejection`."""

    model: str
    matches: list[Match]
    timings_ms: dict[str, float]
    ray: np.ndarray
    distance_mm: float
    score: str = "descriptor"
    confidences: list[float | None] = field(default_factory=list)
    reason: str | None = None
    #: per match, how far its object's origin lies along `ray` (mm): `distance_mm` when it was sent, else
    #: the measured surface plus the match's template offset (`service.origin`)
    origins_mm: list[float] = field(default_factory=list)


@dataclass
class Decoded:
    """A query's images, decoded, and the model its modality picks."""

    modality: str
    embedder: Embedder
    rgb: np.ndarray | None
    depth: np.ndarray | None


@dataclass
class Patches:
    """The query cut as the network takes it, once per turn. rgb (n, S, S, 3) uint8 or None; depth
    (n, S, S) mm or None; offsets (n,) degrees of roll undone; distance (mm) the window was cut at, along
    `ray` (3,), the unit ray through the centre in the query's camera (for a patch, the patch camera's)."""

    rgb: np.ndarray | None
    depth: np.ndarray | None
    offsets: np.ndarray
    distance: float
    ray: np.ndarray


def recognise(state: AppState, q: Query) -> Result:
    """What `POST /recognize` answers: the k best distinct (object, viewpoint) answers, nearest first."""
    t0 = time.perf_counter()
    d = decode(state, q)
    return recognise_decoded(state, q, d, decode_s=time.perf_counter() - t0)


def recognise_decoded(state: AppState, q: Query, d: Decoded, decode_s: float | None = None) -> Result:
    """From decoded images to the answer, what `recognise` (so the route) runs after `decode`: the patch
    and its turns (`query_turns`), their descriptors in one batch, the k distinct answers over every
    in-plane variant. `posedesc bench` times this call. `decode_s`: the seconds decoding took, reported
    as `decode` and counted in `total` (omitted when None)."""
    t1 = time.perf_counter()
    step = d.embedder.info.inplane_step
    offsets = turn_offsets(state.settings.query_turns, state.templates.inplane_spacing(step))
    p = cut(q, d.rgb, d.depth, d.embedder.info.spec, offsets)
    described, keep = foreground(d, p) if d.embedder.has_mask else (p, None)
    t2 = time.perf_counter()
    # a masked query's depth was filled before the mask emptied the rest (`foreground`)
    desc = d.embedder.embed_patches(described.rgb, described.depth, p.distance, fill=keep is None)
    t3 = time.perf_counter()
    variants = len(state.templates.inplane(step))
    snap = state.store.snapshot
    rerank = state.settings.rerank if d.embedder.has_local and snap.models[d.modality].local else 0
    score = "local" if rerank else "descriptor"
    calibration = read_calibrations(d.embedder.info.extra, d.embedder.path.name).get(score)
    listed = max(q.k, LISTED if calibration and calibration.statistic != "distance" else 0)  # for `judge`
    matches = snap.answers(d.modality, desc, max(listed, rerank), p.offsets, variants)
    t4 = time.perf_counter()
    if rerank:
        s = state.settings
        mask = None if keep is None else (float(p.offsets[0]), keep[0])
        how = Scoring(mask, s.mask_coverage, s.relief_weight)
        spacing = state.templates.inplane_spacing(step)
        sweep = (s.roll_sweep, [float(a) for a in state.templates.inplane(step)])
        matches = rerank_local(
            snap, q, d, matches, how, s.roll_refine, spacing, listed, s.refine_rounds, sweep
        )
    t5 = time.perf_counter()
    verdict = judge(matches[:listed], score, calibration, state.settings.reject_above)
    matches = matches[: q.k]
    before = {} if decode_s is None else {"decode": decode_s}
    ms = {
        **before,
        "patch": t2 - t1,
        "embed": t3 - t2,
        "search": t4 - t3,
        **({"rerank": t5 - t4} if rerank else {}),
        "total": t5 - t1 + (decode_s or 0.0),
    }
    timings = {k: round(v * 1000, 2) for k, v in ms.items()}
    measured = q.distance_mm is None and p.depth is not None
    depth0 = None if p.depth is None else p.depth[0]  # the surface as measured, not as masked
    origins = origin_distances(snap, matches, p.distance, depth0, d.embedder.info.window_mm, measured)
    return Result(
        state.model_names[d.modality],
        matches,
        timings,
        p.ray,
        p.distance,
        score,
        verdict.confidences[: q.k],
        verdict.reason,
        origins,
    )


@dataclass(frozen=True)
class Scoring:
    """How the re-ranking scores a stored template against the query (`local_scores`). `mask`: (in-plane,
    mask (S, S)) of the query cut at that in-plane, as the descriptor's stage found it: turned to each
    roll (`turn_masks`) rather than found again, which would run the mask head once a roll. `coverage`:
    `index.local.masked_distance`'s weight of the query's mask left outside a template's silhouette.
    `relief`: the weight of `index.local.relief_distance` (the query's depth against the template's
    shape, in windows) added to the score where both have depth: the query's depth and a template stored
    with its relief (`index.local.with_relief`)."""

    mask: tuple[float, np.ndarray] | None = None
    coverage: float = 0.0
    relief: float = 0.0


@dataclass(frozen=True)
class Cut:
    """The query cut upright at one roll, as the re-ranking compares it: the local features (F,), its mask
    (S, S) bool or None, and its relief (`index.local.relief`: values and shares, (G * G,) each) or None
    without depth."""

    features: np.ndarray
    mask: np.ndarray | None
    relief: tuple[np.ndarray, np.ndarray] | None


#: `index.local.relief_distance`'s clip: a cell's residual depth counts up to this (mm). Chosen with the
#: weight on validation frames (README, Evaluation; 10 mm tied), kept wide for real depth: a real Kinect
#: frame differs from its render by a median absolute 4.2 mm on object pixels (README, Data)
RELIEF_CLIP_MM = 20.0


def rerank_local(
    snap: Snapshot,
    q: Query,
    d: Decoded,
    matches: list[Match],
    how: Scoring = Scoring(),
    refine: int = 0,
    spacing: float = 0.0,
    k: int | None = None,
    rounds: int = 1,
    sweep: tuple[int, Sequence[float]] = (0, ()),
) -> list[Match]:
    """The answers re-ranked by local similarity: the query is cut once per roll the answers give
    (turned upright for each), and its local features (`index.embed.LOCAL_NAME`, the pretrained trunk's
    map) compared with those of each answer's upright template, cell by cell where the object is
    (`index.local.masked_distance`): the template's silhouette, and the query's mask when the model has
    one (a head on the trunk, or the depth's for RGB-D); with depth, also their reliefs (`Scoring`).
    Templates stored without silhouettes (older stores) are compared as whole maps (`l2`). An answer whose
    viewpoint has no local features keeps its place after those that have. `refine` > 0: the best
    `refine` answers are also compared at the viewpoints around theirs and at their roll +- `spacing` / 3
    (`spacing`: the templates' in-plane step), and keep the pose that scores best (`service.refine`).
    Measured on validation frames (README, Evaluation). `k`: only the best k answers are wanted (the rest
    are not made). `rounds`: rounds of refinement, each from where the last left the answers, its roll
    turn halved. `sweep` (n, the templates' in-plane angles): before refinement, the best n answers are
    also compared at every other in-plane angle of their viewpoint, and each keeps the roll that scores
    best (`_swept`)."""
    local = snap.models[d.modality].local
    every = [local_key(m.object_id, m.azimuth, m.elevation) for m in matches]
    have = [i for i, k in enumerate(every) if k in local]
    if not have:
        return matches
    keys = [every[i] for i in have]
    rolls = [round(matches[i].inplane, 3) for i in have]
    cuts: dict[float, Cut] = {}  # the query's cuts, shared with refinement
    score = local_scores(q, d, [local[k] for k in keys], rolls, how, cuts)
    first = list(zip(keys, rolls, strict=True))
    # every pose scored, so that the sweep and the refinement score none twice: the same template against
    # the same cut of the query scores the same
    known = {pose: float(s) for pose, s in zip(first, score, strict=True)}
    if sweep[0] > 0 and len(sweep[1]) > 1:
        score, rolls = _swept(q, d, local, score, keys, rolls, how, sweep, cuts, known)
    if refine > 0:
        score, keys, rolls = _refined(
            q, d, local, score, keys, rolls, how, refine, spacing, cuts, known, rounds
        )
    order, seen = np.argsort(score, kind="stable"), set()
    out: list[Match] = []
    for j in order:  # two answers refined to one viewpoint: the better one stays
        if k is not None and len(out) >= k:
            break
        if keys[j] in seen:
            continue
        seen.add(keys[j])
        m = replace(matches[have[j]], distance=float(score[j]))
        if (keys[j], rolls[j]) != first[j]:  # refined
            m = replace(m, azimuth=keys[j][1], elevation=keys[j][2], inplane=rolls[j])
        out.append(m)
    return (out + [m for i, m in enumerate(matches) if every[i] not in local])[:k]


def _swept(
    q: Query,
    d: Decoded,
    local: Mapping[Key, np.ndarray],
    score: np.ndarray,
    keys: list[Key],
    rolls: list[float],
    how: Scoring,
    sweep: tuple[int, Sequence[float]],
    cuts: dict[float, Cut],
    known: dict[tuple[Key, float], float],
) -> tuple[np.ndarray, list[float]]:
    """The best n answers (`sweep`: n, angles) compared also at every other of the templates' in-plane
    angles (shifted by the answer's own offset from its nearest angle, a turn of the query's), each
    template read once for all of them (`scores_across_rolls`); each keeps the roll that scores best. The
    descriptor gives each viewpoint one roll, its nearest variant's, and for an occluded object
    that roll is often wrong where the viewpoint is right (README, Evaluation). The query's cuts at those
    rolls are mostly made already (`cuts`): the re-ranking's answers span the turn. `known`: the poses
    scored so far, to which this adds its own."""
    turns = np.asarray(sweep[1], float)
    best = np.argsort(score, kind="stable")[: sweep[0]]
    by_gap: dict[float, list[int]] = {}  # answers by their offset from the nearest angle (a query turn's)
    offsets = np.asarray(wrap_degrees(np.asarray(rolls, float)[best, None] - turns[None]))
    nearest = offsets[np.arange(len(best)), np.argmin(np.abs(offsets), axis=1)]
    for j, off in zip(best, nearest, strict=True):
        by_gap.setdefault(round(float(off), 3), []).append(int(j))
    score, rolls = score.copy(), list(rolls)
    for gap, group in by_gap.items():
        turned = sorted({round(float(wrap_degrees(a + gap)), 3) for a in turns})
        table = scores_across_rolls(q, d, [local[keys[j]] for j in group], turned, how, cuts)
        for j, row in zip(group, table, strict=True):
            for r, s in zip(turned, row, strict=True):
                known.setdefault((keys[j], r), float(s))  # a pose scored already keeps its score
            i = int(np.argmin(row))
            if known[(keys[j], turned[i])] < score[j]:
                score[j], rolls[j] = known[(keys[j], turned[i])], turned[i]
    return score, rolls


#: viewpoint refinement: the nearest other viewpoints tried (within 1.5 neighbour steps: `service.refine`)
NEAR_VIEWS = 6


def _refined(
    q: Query,
    d: Decoded,
    local: Mapping[Key, np.ndarray],
    score: np.ndarray,
    keys: list[Key],
    rolls: list[float],
    how: Scoring,
    refine: int,
    spacing: float,
    cuts: dict[float, Cut],
    known: dict[tuple[Key, float], float],
    rounds: int = 1,
) -> tuple[np.ndarray, list[Key], list[float]]:
    """The best `refine` answers compared also at the viewpoints around theirs and at their roll +- a
    third of the in-plane `spacing` (`service.refine`); each keeps the (viewpoint, roll) scoring best.
    `rounds` > 1: again from there, the roll's turn halved each round (a sixth, a twelfth, ...). `known`:
    the poses scored so far (`rerank_local`), to which this adds its own; none is scored twice."""
    table = TABLES.of(local)
    score, keys, rolls = score.copy(), list(keys), list(rolls)
    best = np.argsort(score, kind="stable")[:refine]
    for step in range(rounds):  # each round from where the last left each answer, the roll's turn halved
        turn = spacing / (3 * 2**step)
        turns = (0.0, -turn, turn) if spacing > 0 else (0.0,)
        tried: list[tuple[int, Key, float]] = []
        for j in best:
            views = [keys[j], *table[keys[j][0]].near(keys[j], NEAR_VIEWS)]
            for o in turns:
                r = round(float(wrap_degrees(rolls[j] + o)), 3)
                tried += [(int(j), v, r) for v in views if (v, r) != (keys[j], rolls[j])]
        new = list(dict.fromkeys((v, r) for _, v, r in tried if (v, r) not in known))
        if new:
            more = local_scores(q, d, [local[v] for v, _ in new], [r for _, r in new], how, cuts)
            known |= {pose: float(s) for pose, s in zip(new, more, strict=True)}
        for j, v, r in tried:
            if known[(v, r)] < score[j]:
                score[j], keys[j], rolls[j] = known[(v, r)], v, r
    return score, keys, rolls


def local_scores(
    q: Query,
    d: Decoded,
    refs: Sequence[np.ndarray],
    rolls: Sequence[float],
    how: Scoring = Scoring(),
    cuts: dict[float, Cut] | None = None,
) -> np.ndarray:
    """The re-ranking's score of each stored template (`refs`: local features, and silhouettes and relief
    where stored) against the query cut upright at its roll (`rolls`, degrees), scored as `how` says.
    `cuts`: the query's cuts by roll, filled here; a roll found in it is not cut again (the refinement
    asks again for rolls the re-ranking cut). Shape: (N,)."""
    cuts = {} if cuts is None else cuts
    _cut_rolls(q, d, rolls, how.mask, cuts)
    distinct = sorted(set(rolls))
    feats = np.stack([cuts[r].features for r in distinct])
    where = {r: i for i, r in enumerate(distinct)}
    order = np.argsort([where[r] for r in rolls], kind="stable")  # one roll's templates side by side
    row = np.array([where[rolls[i]] for i in order], int)
    grid = d.embedder.local_grid
    t, silhouettes, shape = split_stored(np.stack([np.asarray(refs[i]) for i in order]), feats.shape[1], grid)
    if silhouettes is None:  # no silhouettes stored
        score = l2(feats[row], t)
    else:
        masks = [m for r in distinct if (m := cuts[r].mask) is not None]  # all or none: one model, one query
        query_mask = cell_weights(np.stack(masks), grid)[row] if masks else None
        score = masked_distance(cell_cosines(feats, t, grid, row), silhouettes, query_mask, how.coverage)
        if (reliefs := _reliefs(how, cuts, distinct, shape)) is not None:
            values, shares, theirs = reliefs
            clip = RELIEF_CLIP_MM / d.embedder.info.window_mm
            score = score + how.relief * relief_distance(
                values[row], shares[row], theirs, _f32(silhouettes), clip
            )
    out = np.empty_like(score)
    out[order] = score
    return out


def _reliefs(
    how: Scoring, cuts: Mapping[float, Cut], rolls: Sequence[float], shape: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The query's reliefs at `rolls` (values, shares: (R, G * G) each) and the templates' (`shape`, as
    float32) when the score weighs them: a relief weight, templates stored with theirs and a query with
    depth; else None."""
    reliefs = [cuts[r].relief for r in rolls]
    if not how.relief or shape is None or any(x is None for x in reliefs):
        return None
    values, shares = zip(*reliefs, strict=True)  # none is None here
    return np.stack(values), np.stack(shares), _f32(shape)


def _f32(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, np.float32)


def _cut_rolls(
    q: Query,
    d: Decoded,
    rolls: Sequence[float],
    mask: tuple[float, np.ndarray] | None,
    cuts: dict[float, Cut],
) -> None:
    """Fills `cuts` with the query's cuts at each of `rolls` it lacks (`local_scores`)."""
    missing = sorted(set(rolls) - cuts.keys())
    if not missing:
        return
    p = cut(q, d.rgb, d.depth, d.embedder.info.spec, missing)  # undoes each roll: the object upright
    keep = None
    if mask is not None:
        spec = d.embedder.info.spec
        keep = np.stack([turn_masks(mask[1][None], r - mask[0], spec)[0] for r in missing])
        p = masked(filled(p), keep)
    elif d.embedder.has_mask:
        p, keep = foreground(d, p)
    window = d.embedder.info.window_mm
    x = batch_inputs(d.modality, p.rgb, p.depth, p.distance, window, fill=keep is None)
    shapes = None
    if p.depth is not None:  # the depth as cut (holes filled, emptied outside the mask): its relief
        distance = np.full(len(missing), p.distance, np.float32)
        shapes = relief(p.depth, distance, d.embedder.local_grid, window, keep)
    for i, (r, f) in enumerate(zip(missing, d.embedder.local(x), strict=True)):
        reliefs = None if shapes is None else (shapes[0][i], shapes[1][i])
        cuts[r] = Cut(f, None if keep is None else keep[i], reliefs)


def scores_across_rolls(
    q: Query,
    d: Decoded,
    refs: Sequence[np.ndarray],
    rolls: Sequence[float],
    how: Scoring,
    cuts: dict[float, Cut],
) -> np.ndarray:
    """`local_scores` of every template (`refs`) against the query cut at every one of `rolls`, each
    template read once (`index.local.cell_cosines_across`). Shape: (N, R)."""
    _cut_rolls(q, d, rolls, how.mask, cuts)
    grid = d.embedder.local_grid
    feats = np.stack([cuts[r].features for r in rolls])
    t, silhouettes, shape = split_stored(np.stack([np.asarray(f) for f in refs]), feats.shape[1], grid)
    n, r = len(t), len(rolls)
    if silhouettes is None:  # no silhouettes stored: the pairs one by one
        pairs = [(i, j) for i in range(n) for j in range(r)]
        flat = local_scores(q, d, [refs[i] for i, _ in pairs], [rolls[j] for _, j in pairs], how, cuts)
        return flat.reshape(n, r)
    masks = [m for m in (cuts[x].mask for x in rolls) if m is not None]  # all or none: one model, one query
    query_mask = cell_weights(np.stack(masks), grid) if masks else None
    cos = cell_cosines_across(feats, t, grid)
    score = masked_distance_across(cos, _f32(silhouettes), query_mask, how.coverage)
    if (reliefs := _reliefs(how, cuts, rolls, shape)) is not None:
        clip = RELIEF_CLIP_MM / d.embedder.info.window_mm
        values, shares, theirs = reliefs
        score = score + how.relief * relief_distance_across(values, shares, theirs, _f32(silhouettes), clip)
    return score


def foreground(d: Decoded, p: Patches) -> tuple[Patches, np.ndarray]:
    """The query's patches with what the model's mask (`index.embed.MASK_NAME`) says is not the centred
    object black (colour) and empty (depth), as a template's background is, and that mask (N, S, S)
    bool. The descriptor and the local features then see the object, not what stands around it:
    measured on validation frames (README, Evaluation), the rgb network within 20 deg 44 -> 50 % with its
    mask head against the same network re-ranked over template silhouettes only. The mask reads the depth
    as measured: a pixel without depth is not known to lie in an RGB-D model's band, so it is not the
    object's (filling first flooded a patch cut out on an empty background with the object's depth, and
    its mask with it). The depth's holes are then filled (`filled`) and what the mask empties stays empty."""
    x = batch_inputs(d.modality, p.rgb, p.depth, p.distance, d.embedder.info.window_mm, fill=False)
    keep = d.embedder.mask(x)
    return masked(filled(p), keep), keep


def filled(p: Patches) -> Patches:
    """The patches with their depth's holes filled (`index.patches.fill_depth`), as the network takes
    them. Before a mask: filling after it filled the emptied background from the object, 15 ms a query
    of the RGB-D re-ranking for nothing its network reads (measured on validation frames)."""
    return p if p.depth is None else replace(p, depth=fill_depth(p.depth))


def masked(p: Patches, keep: np.ndarray) -> Patches:
    """The patches black (colour) and empty (depth) where `keep` (N, S, S) bool is False."""
    rgb = None if p.rgb is None else p.rgb * keep[..., None].astype(p.rgb.dtype)
    depth = None if p.depth is None else np.where(keep, p.depth, 0.0).astype(np.float32)
    return replace(p, rgb=rgb, depth=depth)


def decode(state: AppState, q: Query) -> Decoded:
    """Checks what was sent, picks the model of its modality and decodes the images."""
    if q.k > state.settings.max_k:
        raise ApiError(422, f"k: must be at most {state.settings.max_k}, got {q.k}")
    if q.rgb is None and q.depth is None:
        raise ApiError(422, "send an `rgb` image, a `depth` image, or both")
    modality = (
        "rgbd" if q.rgb is not None and q.depth is not None else "rgb" if q.rgb is not None else "depth"
    )
    embedder = state.embedders.get(modality)
    if embedder is None:
        loaded = ", ".join(sorted(state.embedders))
        raise ApiError(422, f"no {modality} model is loaded (loaded: {loaded}); send what one of them takes")
    px = state.settings.max_image_pixels
    rgb = None if q.rgb is None else read_rgb(q.rgb, px)
    depth = None if q.depth is None else read_depth(q.depth, q.depth_scale, px)
    if rgb is not None and depth is not None and rgb.shape[:2] != depth.shape:
        raise ApiError(
            422,
            f"rgb is {rgb.shape[1]} x {rgb.shape[0]} px but depth is {depth.shape[1]} x {depth.shape[0]} px",
        )
    return Decoded(modality, embedder, rgb, depth)


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
) -> Patches:
    """The patches of a decoded query, one per turn in `offsets` (degrees of roll undone)."""
    given = [f for f in FRAME_FIELDS if getattr(q, f) is not None]
    if given and len(given) < len(FRAME_FIELDS):
        missing = ", ".join(f for f in FRAME_FIELDS if f not in given)
        raise ApiError(422, f"a full frame needs fx, fy, cx, cy, u and v; missing: {missing}")
    if given:
        K, centre, distance = _from_frame(q, rgb, depth, spec)
    else:
        rgb, depth, distance = _from_patch(q, rgb, depth, spec)
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
        raise ApiError(422, "the depth patch is all zero: no depth was measured around the object")
    if depths is not None and q.distance_mm is not None:  # a measured distance agrees by construction
        s = spec.size
        centre_quarter = depths[0][3 * s // 8 : 5 * s // 8, 3 * s // 8 : 5 * s // 8]
        check_given_distance(centre_quarter[centre_quarter > 0], distance, spec.window_mm, q.depth_scale)
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
    K = np.array([[q.fx, 0.0, q.cx], [0.0, q.fy, q.cy], [0.0, 0.0, 1.0]], dtype=float)
    distance = q.distance_mm
    if distance is None:
        if depth is None:
            raise ApiError(
                422, "a colour-only frame needs distance_mm (from the camera to the object's origin, mm)"
            )
        distance = _measured(_depth_at(depth, K, u, v))
        check_frame_distance(distance, (K[0, 0] + K[1, 1]) / 2, spec.window_mm, spec.size, q.depth_scale)
    return K, (u, v), distance


def _depth_at(depth: np.ndarray, K: np.ndarray, u: float, v: float, r: int = 7) -> float:
    """Distance (mm, along the ray) of the surface at (u, v): median of the valid depths around it."""
    iu, iv = int(u), int(v)
    win = depth[max(0, iv - r) : iv + r + 1, max(0, iu - r) : iu + r + 1]
    valid = win[win > 0]
    if valid.size == 0:
        raise ApiError(422, f"no depth around the centre ({u:g}, {v:g}); send distance_mm")
    ray = np.linalg.inv(K) @ np.array([u, v, 1.0])
    return float(np.median(valid) * np.linalg.norm(ray))


def _from_patch(q: Query, rgb, depth, spec: PatchSpec):
    """A patch already centred on the object, spanning the model's metric window: resized to the input."""
    size = spec.size
    h, w = (rgb if rgb is not None else depth).shape[:2]
    if abs(h - w) > 1:
        raise ApiError(
            422, f"a patch must be square ({w} x {h} px); for a full frame send fx, fy, cx, cy, u and v"
        )
    rgb_p = None if rgb is None else cv2.resize(rgb, (size, size), interpolation=cv2.INTER_AREA)
    depth_p = None if depth is None else cv2.resize(depth, (size, size), interpolation=cv2.INTER_NEAREST)
    distance = q.distance_mm
    if distance is None and depth_p is not None:
        c = depth_p[size * 3 // 8 : size * 5 // 8, size * 3 // 8 : size * 5 // 8]
        distance = _measured(float(np.median(c[c > 0]))) if (c > 0).any() else None
        if distance is not None:
            check_patch_distance(distance, spec.window_mm, q.depth_scale)
    return rgb_p, depth_p, distance or 400.0


def _measured(distance: float) -> float:
    if not MIN_DISTANCE_MM <= distance <= MAX_DISTANCE_MM:
        raise ApiError(
            422,
            f"the depth at the centre says {distance:.3g} mm, outside {MIN_DISTANCE_MM:g} to "
            f"{MAX_DISTANCE_MM:g} mm: is depth_scale right?",
        )
    return distance
