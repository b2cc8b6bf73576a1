"""The service protocol (`posedesc evaluate --protocol service`): the evaluation that is the service.

Every object of the dataset (or of `--objects`) is registered by the service's own registration
(`index.templates.register.register` into a real store in a temporary folder, with the service's settings:
`POSEDESC_*` variables, overridden by the command's options). Every test instance is then sent to
`service.recognition.recognise`, the function `POST /recognize` runs, as a user sends it
(`evaluation.queries`): the frame as image bytes, the camera, the centre (u, v) where the object's origin
projects, and for colour the distance to the origin along that ray (‖t‖); with depth, the frame's depth
image and no distance (the service measures it).
A dataset with colour but no depth (LM-O) sends its real colour with depth rendered from the frame's
ground truth (`evaluation.masks.rendered_depth`, 16-bit PNG in mm), unless synthetic scenes are asked for.

Each of the k = 22 distinct answers gives a pose: view_to_pose(View(azimuth, elevation, in-plane)) along
the ray through (u, v). It is scored by the 3-D rotation error against the annotated R (symmetry-aware,
in-plane included) and by the viewing-direction error (`index.geometry.pose_error`); a wrong object counts 180°.
The open set is on, as for a user: a query the service answers "no known object" (best: null, the
rejection of `service.rejection`) is a miss at every k (`evaluation.results.open_set`); the figures as
ranked, with nothing rejected, are kept beside them ("open_set_off" in the JSON).

HOG and LineMOD see what the service sees: the patch the service's own `cut` makes (the unturned query)
and the very template views it registered for the model (in-plane variants included), rendered again;
their rankings collapse in-plane variants to distinct (object, viewpoint) answers as the service does."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Mapping, Sequence
from contextlib import closing, nullcontext
from pathlib import Path
from typing import TypedDict

import cv2
import numpy as np
import trimesh

from evaluation.bop.recall import MSPD_REFERENCE_WIDTH
from evaluation.bop.scores import Best, bop_block, estimates, object_model
from evaluation.bop.vsd import vsd_for
from evaluation.config import Config
from evaluation.masks import black_outside, visible_masks
from evaluation.paper import ours
from evaluation.paper.methods import rank
from evaluation.paper.metric import K_MAX, WRONG_OBJECT
from evaluation.paper.neighbours import distinct_rows
from evaluation.paper.samples import RENDERED, SYNTHETIC, SYNTHETIC_NOTE, Samples, instances_of, served_data
from evaluation.paper.templates import render_template_set, service_symmetry
from evaluation.progress import bar
from evaluation.queries import frame_files, patch_query, png, query
from evaluation.results import Evaluation, MethodResult, open_set
from evaluation.rolls import RolledFrames
from index.data.bop import BopDataset, Instance
from index.features.embed import Embedder
from index.geometry.pose import View, pose_to_view, view_to_pose
from index.geometry.pose_error import rotation_errors, view_errors
from index.geometry.symmetry import Symmetry
from index.templates.register import template_views
from index.templates.render import Renderer
from index.templates.windows import object_window
from service.errors import ApiError
from service.pipeline.answer import Result
from service.pipeline.query import Query, cut, decode, shape_only
from service.recognition import recognise
from service.rejection import read_calibrations
from service.settings import Settings
from service.state import AppState, close_state, load_state


def rendered_note(kind: str) -> str:
    """What the depth of `kind` (real colour, rendered depth; rendered depth) shows and what it lacks."""
    return (
        f"{kind}: annotated objects and the table only; unannotated clutter has the table's depth (none "
        "where no table plane is found). The depth is rendered from the ground-truth poses of every "
        "annotated object of the frame, the table plane under them where no object is, through the "
        "sensor model, and sent as a 16-bit PNG in mm"
    )


class _Options(TypedDict, total=False):
    inplane_step: float
    inplane_max: float
    query_turns: int


def evaluate_served(cfg: Config) -> Evaluation:
    dataset = BopDataset(cfg.dataset)
    obj_ids = list(cfg.objects) if cfg.objects else dataset.obj_ids
    instances = instances_of(cfg, dataset, obj_ids)
    kind = served_data(cfg.modality, instances, cfg.synthetic)
    options: _Options = {}  # the command's options override the settings only where given
    if cfg.inplane_step is not None:
        options["inplane_step"] = cfg.inplane_step
    if cfg.inplane_max is not None:
        options["inplane_max"] = cfg.inplane_max
    if cfg.query_turns is not None:
        options["query_turns"] = cfg.query_turns
    symmetries = {o: dataset.symmetry(o) for o in obj_ids}
    seconds: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="posedesc-evaluate-") as tmp:
        settings = Settings(data_dir=Path(tmp), demo_objects=False, **options)
        embedder = Embedder(cfg.model, settings.threads)  # as the service loads it
        if embedder.modality != cfg.modality:
            raise ValueError(f"{cfg.model} is a {embedder.modality} model, not {cfg.modality}")
        state = load_state(settings, served_models(embedder, settings.threads))
        try:
            t0 = time.perf_counter()
            meshes, dataset_ids = register_objects(state, dataset, obj_ids)
            distractors = register_distractors(state, cfg.distractors)
            seconds["register"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            depth_errors: list[tuple[float, float]] = []
            bop = None if cfg.patches else _BopAnswers()  # a patch's poses are in its own camera
            samples, answers, call_ms, refused, instances, dropped = _ask(
                state, dataset, instances, kind, cfg, dataset_ids, meshes, depth_errors, bop
            )
            seconds["ours"] = time.perf_counter() - t0
            n_templates = state.store.snapshot.models[cfg.modality].size
            routed = cfg.modality == "rgbd" and "depth" in state.embedders and shape_only(state.store)
        finally:
            close_state(state)

    step = embedder.info.inplane_step
    variants = len(state.templates.inplane(step))
    notes = [SYNTHETIC_NOTE] if kind == SYNTHETIC else [rendered_note(kind)] if kind in RENDERED else []
    if cfg.oracle_mask:
        notes.append("oracle mask: each frame was sent black outside the instance's true visible mask")
    if cfg.rolls:
        notes.append(
            f"each frame sent at camera rolls of {', '.join(f'{r:g}' for r in cfg.rolls)} deg (turned about "
            "the principal point, poses turned with it: evaluation/rolls.py); instances whose centre left "
            f"the frame at a roll were not sent at it ({dropped})"
        )
    if routed:
        notes.append(
            "every registered object is shape-only: the RGB-D frames were answered by the depth model beside "
            "the RGB-D one, as the service answers them (service.pipeline.query.shape_only)"
        )
    if refused:
        notes.append(f"the service refused {len(refused)} queries (counted as wrong): {sorted(set(refused))}")
    ev = Evaluation(cfg, samples, None, symmetries, seconds=seconds, notes=notes)
    ev.extra = {
        "n_templates": n_templates,
        **({"distractors": distractors} if cfg.distractors is not None else {}),
        "service": {
            "model_inplane_step": step,
            "inplane_step": settings.inplane_step,
            "inplane_max": settings.inplane_max,
            "templates_per_viewpoint": variants,
            "query_turns": settings.query_turns,
            "level": settings.level,
            # None: each score kind's threshold from the model's metadata (`calibrations`)
            "reject_above": settings.reject_above,
            "calibrations": sorted(read_calibrations(embedder.info.extra, cfg.model.name)),
        },
        **({"rolls": list(cfg.rolls), "rolls_dropped": dropped} if cfg.rolls else {}),
        "timing_ms": {
            "recognise_median": round(float(np.median(call_ms)), 2),
            "recognise_p90": round(float(np.percentile(call_ms, 90)), 2),
            "calls": len(call_ms),
        },
    }
    if depth_errors:  # measured from depth: where the answers put the origin, against ‖t‖
        ev.extra["origin_distance_mm"] = origin_errors(np.array(depth_errors))
    if bop is not None:
        ev.extra["bop"] = _bop_scores(dataset, instances, bop, cfg.min_visib, cfg.modality, kind)
        ev.bop_estimates = estimates(instances, bop.bests)
    else:
        ev.notes.append(
            "patches: each instance sent as the patch a user would cut from its frame through its object's "
            "window, with that window and the distance, no camera (evaluation.queries.patch_query); no BOP "
            "block (a patch's pose is in the patch's own camera)"
        )
    obj, views, rejected = answers
    rot, view, same = score(obj, views, instances, symmetries)
    ranked = MethodResult(rot, same, seconds["ours"], view_errors=view, call_ms=np.asarray(call_ms))
    ev.results["ours"] = open_set(ranked, rejected)
    ev.notes.append(
        f"open set on: {int(rejected.sum())} of {len(rejected)} queries answered 'no known object' (best: "
        "null, service.rejection) count as misses at every k; open_set_off: the same answers as ranked"
    )

    baselines = [m for m in cfg.methods if m != "ours"]
    if baselines:
        t0 = time.perf_counter()
        views_of = {
            o: template_views(service_symmetry(symmetries[o]), state.templates, step) for o in obj_ids
        }
        with bar(sum(map(len, views_of.values())), "render templates", "template") as b:
            ev.templates = render_template_set(
                meshes, views_of, cfg.modality, embedder.info.window_mm, progress=b.update
            )
        seconds["render_templates"] = time.perf_counter() - t0
        t = ev.templates
        keys = (t.obj_ids, np.array([v.azimuth for v in t.views]), np.array([v.elevation for v in t.views]))
        t_views = np.array([(v.azimuth, v.elevation, v.inplane) for v in t.views]).reshape(-1, 3)
        for name in baselines:
            t0 = time.perf_counter()
            r = rank(name, embedder, t, ev.samples, min(len(t), K_MAX * variants), cfg.linemod_threshold)
            ev.notes += r.notes
            idx, scores = distinct_rows(r.neighbours, r.scores, keys, K_MAX)
            obj = np.where(idx >= 0, t.obj_ids[np.maximum(idx, 0)], -1)
            rot, view, same = score(obj, t_views[np.maximum(idx, 0)], instances, symmetries)
            seconds[name] = time.perf_counter() - t0
            ev.results[name] = MethodResult(
                rot,
                same,
                seconds[name],
                neighbours=idx,
                scores=scores,
                view_errors=view,
                separation=r.separation,
            )
    return ev


def register_objects(
    state: AppState, dataset: BopDataset, obj_ids: Sequence[int]
) -> tuple[dict[int, trimesh.Trimesh], dict[int, int]]:
    """Every object of `obj_ids` (dataset ids) through the service's registration, as `POST /objects`
    registers it, into `state`'s store: each object's mesh, and the dataset id of each store id."""
    meshes, dataset_ids = {}, {}
    with bar(len(obj_ids), "register", "object") as b:
        for o in obj_ids:
            meshes[o] = dataset.mesh(o, max_faces=state.settings.max_faces)  # as POST /objects loads it
            reg = state.register_mesh(meshes[o], f"obj_{o:06d}", service_symmetry(dataset.symmetry(o)))
            dataset_ids[reg.record.object_id] = o
            b.update()
    return meshes, dataset_ids


def served_models(embedder: Embedder, threads: int | None = None) -> dict[str, Embedder]:
    """The models a service with `embedder` in its models folder loads for its modality: the model, and for
    an RGB-D one the depth model beside it (posedesc-depth.onnx), which answers RGB-D frames while every
    registered object is shape-only (`service.pipeline.query.shape_only`)."""
    out = {embedder.modality: embedder}
    beside = embedder.path.parent / "posedesc-depth.onnx"
    if embedder.modality == "rgbd" and beside.is_file():
        depth = Embedder(beside, threads)
        if depth.modality == "depth":
            out["depth"] = depth
    return out


def register_distractors(state: AppState, folder: Path | None) -> dict[str, object]:
    """Every object of the BOP dataset at `folder` registered as `register_objects` registers (none when
    None): never asked about, and not in the answers' dataset ids, so an answer naming one is wrong."""
    if folder is None:
        return {}
    other = BopDataset(folder)
    names = []
    with bar(len(other.obj_ids), "register distractors", "object") as b:
        for o in other.obj_ids:
            mesh = other.mesh(o, max_faces=state.settings.max_faces)
            names.append(f"distractor_{o:06d}")
            state.register_mesh(mesh, names[-1], service_symmetry(other.symmetry(o)))
            b.update()
    return {"dataset": str(folder), "objects": len(names)}


class _BopAnswers:
    """What BOP's scoring keeps of the answers: each query's best answer (None: rejected, refused or
    none) in the order sent, and the widths (px) of the frames sent."""

    def __init__(self) -> None:
        self.bests: list[Best | None] = []
        self.widths: set[int] = set()


def _best(result: Result, obj_id: int, seconds: float) -> Best | None:
    """The service's best answer as a pose, as the API returns it (`service.poses`); None when it
    answered "no known object" or nothing."""
    if result.reason is not None or not result.matches or obj_id < 0:
        return None
    R, t = result.pose(0)
    return Best(obj_id, R, t, result.confidences[0], seconds)


def _bop_scores(
    dataset: BopDataset,
    instances: Sequence[Instance],
    bop: _BopAnswers,
    min_visib: float,
    modality: str,
    sent: str,
) -> dict:
    """The JSON's "bop" block (`evaluation.bop.scores`): models from the full meshes and models_info; VSD
    where the frames sent have recorded depth (`sent`: `served_data`'s kind)."""
    if len(bop.widths) > 1:
        raise ValueError(f"frames of several widths {sorted(bop.widths)}: MSPD's thresholds need one")
    width = bop.widths.pop() if bop.widths else MSPD_REFERENCE_WIDTH  # every query refused: all missing
    meshes = {o: dataset.mesh(o) for o in {i.obj_id for i in instances}}
    models = {o: object_model(dataset.symmetry_info(o), m) for o, m in meshes.items()}
    vsd = vsd_for(instances, meshes, {o: m.diameter for o, m in models.items()}, sent)
    try:
        block = bop_block(instances, bop.bests, models, width, min_visib, vsd)
    finally:
        if vsd is not None:
            vsd.close()
    if modality == "rgb":  # colour is sent the true centre and distance: the answer's t is the truth's
        block["translation"] = (
            "colour queries are sent the ground truth's centre and distance (as a user with a detector and "
            "a range would), so each answer's t is the true t (te ~ 0): these figures measure the rotation"
        )
    return block


def _ask(
    state,
    dataset,
    instances,
    kind: str,
    cfg: Config,
    dataset_ids: dict[int, int],
    meshes: Mapping[int, trimesh.Trimesh],
    depth_errors: list[tuple[float, float]] | None = None,
    bop: _BopAnswers | None = None,
):
    """Every instance through `recognise`; the unturned patches the service cut (for the baselines),
    its answers (objects, views, and whether the service rejected the best one: "no known object"),
    each call's milliseconds, and the reasons of the queries it refused. With
    `cfg.oracle_mask`, each instance's frame is sent black outside its true visible mask. `depth_errors`
    gets, for each query sent without a distance whose best answer is the right object, the errors (mm)
    of the distance it was cut at (the surface) and of where the answer puts the origin, against ‖t‖.
    With `cfg.rolls`, every frame is sent at each camera roll (`evaluation.rolls`); the instances as
    sent (rolled poses, in the order asked) are returned with how many were dropped (centre out of the
    frame at a roll)."""
    # one renderer for the oracle masks and the rendered depth, on this thread (EGL: a context a thread)
    renderer = Renderer() if cfg.oracle_mask or kind in RENDERED else None
    cache = dict(meshes)  # the frames' other annotated objects join it; `meshes` stays the registered ones
    frames = frame_files(
        dataset, instances, cfg.modality, kind, cfg.seed, renderer, cache, state.settings.max_faces
    )
    rolled = RolledFrames(frames, cfg.rolls or (0.0,))
    embedder = state.embedders[cfg.modality]
    spec = embedder.info.spec
    records = state.store.snapshot.objects
    windows = {o: object_window(records[s].extra, spec.window_mm) for s, o in dataset_ids.items()}
    ordered: list[Instance] = []
    views, rgbs, depths, cut_mm, call_ms, refused = [], [], [], [], [], []
    n = len(instances) * len(rolled.rolls)  # at most: a rolled centre may leave the frame
    obj = np.full((n, K_MAX), -1, int)
    answer_views = np.zeros((n, K_MAX, 3))
    rejected = np.zeros(n, bool)  # answered "no known object" (best: null)
    with bar(n, "recognise") as b, closing(renderer) if renderer else nullcontext():
        for group, rgb, depth, scale, _ in rolled:
            sent = [rgb] * len(group)
            if cfg.oracle_mask and renderer is not None and rgb is not None:
                frame: np.ndarray = cv2.imdecode(np.frombuffer(rgb, np.uint8), cv2.IMREAD_COLOR)  # type: ignore[assignment]  # a file the dataset holds
                masks = visible_masks(renderer, group, meshes, frame.shape[1], frame.shape[0])
                sent = [png(black_outside(frame, m)) for m in masks]
            decoded, decoded_of = None, None
            for inst, rgb in zip(group, sent, strict=True):
                if rgb is not decoded_of or decoded_of is None:  # once a frame, once a mask
                    decoded_of = rgb
                    try:
                        decoded = decode(state, Query(rgb=rgb, depth=depth, depth_scale=scale))
                    except ApiError:
                        decoded = None  # `recognise` says why
                if decoded is not None and bop is not None:
                    image = decoded.rgb if decoded.rgb is not None else decoded.depth
                    bop.widths.add(int(image.shape[1]))  # type: ignore[union-attr]  # a decoded query has one
                q, i = query(inst, rgb, depth, scale), len(ordered)
                t0 = time.perf_counter()
                best = None
                try:
                    if cfg.patches and decoded is not None:
                        q = patch_query(q, decoded, windows[inst.obj_id])
                    result = recognise(state, q)
                    call_ms.append(1000 * (time.perf_counter() - t0))
                    obj[i], answer_views[i], _ = ours.answers(result.matches, dataset_ids, K_MAX)
                    _fitted_views(result, answer_views[i])
                    best = _best(result, int(obj[i, 0]), call_ms[-1] / 1000)
                    rejected[i] = result.reason is not None
                    if depth_errors is not None and q.distance_mm is None and obj[i, 0] == inst.obj_id:
                        true = float(np.linalg.norm(inst.t))
                        depth_errors.append((result.distance_mm - true, result.origins_mm[0] - true))
                    p = (  # (a patch query was cut from the frame already: `patch_query`)
                        cut(
                            q,
                            decoded.rgb,
                            decoded.depth,
                            spec,
                            patch_distance_mm=state.settings.patch_distance_mm,
                        )
                        if decoded is not None and not cfg.patches
                        else None
                    )
                except ApiError as e:
                    refused.append(e.detail)
                    p = None
                ordered.append(inst)
                if bop is not None:
                    bop.bests.append(best)
                views.append(inst.view)
                rgbs.append(None if p is None or p.rgb is None else p.rgb[0])
                depths.append(None if p is None or p.depth is None else p.depth[0])
                cut_mm.append(np.nan if p is None else p.distance)
                b.update()
    size = (spec.size, spec.size)
    samples = Samples(
        obj_ids=np.array([i.obj_id for i in ordered], int),
        frame_ids=np.array([i.frame_id for i in ordered], int),
        visib=np.array([i.visib_fract for i in ordered]),
        views=views,
        rgb=_stack(rgbs, (*size, 3), np.uint8) if cfg.modality in ("rgb", "rgbd") else None,
        depth=_stack(depths, size, np.float32) if cfg.modality in ("depth", "rgbd") else None,
        source=kind,
        cut_mm=np.nan_to_num(np.array(cut_mm), nan=400.0),
    )
    answers = (obj[: len(ordered)], answer_views[: len(ordered)], rejected[: len(ordered)])
    return samples, answers, call_ms, refused, ordered, rolled.dropped


def origin_errors(errors: np.ndarray) -> dict[str, float | int]:
    """Summary of (surface, origin) distance errors (N, 2) mm: the cut distance against the answer's."""
    out: dict[str, float | int] = {"n": len(errors)}
    for j, name in enumerate(("surface", "answer")):
        out[f"{name}_median_error"] = round(float(np.median(errors[:, j])), 1)
        out[f"{name}_median_abs_error"] = round(float(np.median(np.abs(errors[:, j]))), 1)
    return out


def _fitted_views(result: Result, views: np.ndarray) -> None:
    """Each answer the pose fit moved (`service.pipeline.fit`) written into `views` (k, 3) as the view whose
    pose along the query's ray (`Result.ray`: a frame's through the instance's centre, as `score` reads a
    view; a patch's optical axis, its camera looking along that ray) is the fitted rotation (`pose_to_view`
    inverts `view_to_pose` for one ray): the errors are then the fitted pose's."""
    for j in range(min(len(result.fits), len(views))):
        if result.fitted(j) is not None:
            R, _ = result.pose(j)
            view = pose_to_view(R, result.ray / np.linalg.norm(result.ray))
            views[j] = view.azimuth, view.elevation, view.inplane


def _stack(images: list, shape: tuple[int, ...], dtype) -> np.ndarray:
    """The patches; an empty one where the service refused the query."""
    return np.stack([np.zeros(shape, dtype) if a is None else a for a in images]).astype(dtype)


def score(
    obj: np.ndarray,
    answers: np.ndarray,
    instances: Sequence[Instance],
    symmetries: Mapping[int, Symmetry],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The errors of each instance's answers: obj (N, K) dataset object ids, -1 = none; answers (N, K, 3)
    azimuth, elevation, in-plane. Each answer's pose is its view along the ray through the instance's
    centre. Returns (3-D rotation errors, viewing-direction errors, same object), each (N, K);
    a wrong object or none counts 180°."""
    same = obj == np.array([i.obj_id for i in instances])[:, None]
    rot = np.full(obj.shape, WRONG_OBJECT)
    view = np.full(obj.shape, WRONG_OBJECT)
    for i, inst in enumerate(instances):
        hit = np.flatnonzero(same[i])
        if not len(hit):
            continue
        u, v = inst.centre_uv
        ray = np.linalg.inv(inst.K) @ np.array([u, v, 1.0])
        R_est = np.stack([view_to_pose(View(*answers[i, j]), ray)[0] for j in hit])
        symmetry = symmetries[inst.obj_id]
        rot[i, hit] = rotation_errors(R_est, inst.R, symmetry)[:, 0]
        view[i, hit] = view_errors(R_est, inst.R, symmetry, ray)[:, 0]
    return rot, view, same
