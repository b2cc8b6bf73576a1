"""Registering an object, the one code path of the API, `posedesc build-index`, the evaluation and the
benchmarks: mesh -> renders of every template view (on the render thread) -> patches -> descriptors of
every model -> the store, in one transaction for all models.

Template views: the paper's level-3 half-sphere (301 viewpoints; every side's 642 when a registration asks,
`index.templates.viewpoints.VIEWPOINTS`) at 400 mm, times each model's in-plane angles: every multiple of
its metadata's `inplane_step` over the whole turn (`index.features.embed.ModelInfo`), upright only for a
legacy model; settings may override both (`TemplateConfig`). The union of the models' views is rendered
once (in-plane variants are turns of a render, `index.templates.render`); each model embeds its subset.

Costs (`benchmarks/serving/costs.py`, `posedesc bench`; a 21.8k-face mesh): 301 templates a model render in
1.2 s, embedded alongside, 1.35 s in all; the shipped models on a 100-object store, render and embedding
overlapping (`make_templates`), 3.6-3.8 s a registration, the two cores the bound (docs/experiments.md).

Symmetric objects do not need every view (`index.geometry.symmetry`): the views of a "180" object from
azimuth a and a + 180 are the same picture, so only azimuths in [0, 180) are kept; a "full" object looks the
same from every azimuth at one elevation, and the icosphere is 5-fold symmetric about z, so the wedge
[0, 72) holds every elevation of the set. A flip shows the side below as the side above, rolled: from
every side with the whole turn of roll, the upper half's views hold it. The answer for such an object
gives the matched template's pose, one of the equivalent ones.

Each object is seen through the window its size asks for (`index.templates.windows`: chosen here from the mesh's
diameter, stored with its record as `extra["window_mm"]` and `extra["diameter_mm"]`): its templates are
rendered through it, from a distance scaled with it (400 mm for the model's own window), so that every
object fills its templates about alike and is seen with the same perspective.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import TypeVar

import numpy as np
import trimesh

from index.features.embed import Embedder
from index.features.local import with_relief, with_silhouettes
from index.geometry.pose import View
from index.geometry.shape_symmetry import resolve
from index.geometry.symmetry import parse, turns_over
from index.store import ObjectRecord, TemplateSet, TemplateStore
from index.templates import viewpoints as vp
from index.templates.mesh import MeshError, diameter, load_mesh, simplify
from index.templates.render import INVISIBLE, Renderer, RenderWorker, Templates, Uprights
from index.templates.surface import SURFACE_KEY, template_offsets
from index.templates.windows import DIAMETER_KEY, WINDOW_KEY, object_window, window_class

log = logging.getLogger(__name__)
T = TypeVar("T")

#: patches per network run when templates are embedded: the same descriptors as in runs of 150-512 (the
#: activations of a few patches stay in the cache), for less CPU with one intra-op thread. Measured on the
#: shipped rgb model, 300 patches, sizes interleaved, thread CPU time: descriptors 126 ms at 8 against 153
#: at 150-300 (two threads at once: 267 against 322-327), local features 54 against 76 ms at 256
EMBED_BATCH = 8
#: chunks of viewpoints a registration renders and embeds in (`make_templates`): the first chunk's
#: embedding starts when it is rendered, so the fewer the viewpoints a chunk, the sooner both cores work
CHUNKS = 12

#: Told (stage, done, total) as a registration goes: the stage it is waiting on now ("render": the next
#: chunk of views to be rendered; "embed": a chunk to be embedded by every model; they alternate), with
#: the object's views done (rendered and embedded) of all; then "store", its templates stored of all.
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class TemplateConfig:
    level: int = 3  # icosphere subdivisions: 3 = the paper's 301 template viewpoints
    #: in-plane step for every model, degrees (0: upright only); None: each model's own metadata
    inplane_step: float | None = None
    #: variants span +-this (>= 180: the whole turn); None: the whole turn for a model trained with
    #: roll, +-45 for a legacy one
    inplane_max: float | None = None
    distance_mm: float = 400.0  # render distance (LineMOD's); patches are metric, so it barely matters
    #: every side's viewpoints (`index.templates.viewpoints.viewpoints`), not the upper half's only; with
    #: `whole_shape_only`, every side's for a shape-only mesh (a registration that says keeps its own)
    whole: bool = False
    whole_shape_only: bool = False

    def inplane(self, model_step: float = 0.0) -> np.ndarray:
        """In-plane angles of the templates of a model whose metadata says `model_step` (0: legacy)."""
        step = model_step if self.inplane_step is None else self.inplane_step
        span = self.inplane_max if self.inplane_max is not None else (360.0 if model_step > 0 else 45.0)
        return vp.inplane_steps(step, span)

    def inplane_spacing(self, model_step: float = 0.0) -> float:
        """Degrees between neighbouring in-plane templates of such a model; 0 when upright only."""
        step = model_step if self.inplane_step is None else self.inplane_step
        return float(step) if len(self.inplane(model_step)) > 1 else 0.0

    def through(self, window_mm: float, model_window_mm: float) -> TemplateConfig:
        """The config for an object seen through `window_mm`: rendered from a distance scaled with it."""
        if window_mm == model_window_mm:
            return self
        return replace(self, distance_mm=self.distance_mm * window_mm / model_window_mm)


#: an object record's `extra`: whether its mesh has colours, and where its symmetry came from
#: (`index.geometry.shape_symmetry.Resolved`)
TEXTURED_KEY = "textured"
SYMMETRY_FROM_KEY = "symmetry_from"


@dataclass
class Registration:
    """What a registration did: the object's record and seconds spent in render / embed / store."""

    record: ObjectRecord
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def template_views(
    symmetry: str, cfg: TemplateConfig = TemplateConfig(), model_step: float = 0.0
) -> list[View]:
    """The template views of an object with this symmetry for a model whose metadata says `model_step`
    (viewpoint-major: the in-plane variants of a viewpoint are adjacent)."""
    try:
        named = parse(symmetry)
    except ValueError as e:
        raise MeshError(str(e)) from None
    inplane = cfg.inplane(model_step)
    views = vp.sphere_views(cfg.level, inplane, cfg.distance_mm, cfg.whole)
    if cfg.whole and turns_over(symmetry) and vp.whole_turn(inplane):
        # a flip shows the side below as the side above, rolled: the rolls of the upper half's views hold it
        views = [v for v in views if v.elevation > -1e-6]
    wedge = {"none": 360.0, "180": 180.0, "full": 72.0}[named.about_z] if named.axis == "z" else 360.0
    # +1e-6: a vertex on a wedge's edge may come out of arctan2 a hair below it (359.9999... for 0)
    return [v for v in views if (v.azimuth + 1e-6) % 360.0 < wedge]


def model_views(
    symmetry: str, cfg: TemplateConfig, embedders: Mapping[str, Embedder]
) -> dict[str, list[View]]:
    """Each model's template views of an object (they differ when the models' in-plane steps do)."""
    return {m: template_views(symmetry, cfg, e.info.inplane_step) for m, e in embedders.items()}


def _viewpoints(views: Mapping[str, list[View]]) -> list[list[View]]:
    """The union of the models' views, grouped by viewpoint (first-seen order), in-plane sorted."""
    groups: dict[tuple[float, float, float], set[float]] = {}
    for vs in views.values():
        for v in vs:
            groups.setdefault((v.azimuth, v.elevation, v.distance), set()).add(v.inplane)
    return [[View(az, el, ip, d) for ip in sorted(ips)] for (az, el, d), ips in groups.items()]


def render_templates(
    worker: RenderWorker,
    mesh: trimesh.Trimesh | Future[trimesh.Trimesh],
    views: list[View],
    windows: set[float],
    then: Callable[[dict[float, Uprights]], T] | None = None,
) -> Future[tuple[dict[float, Uprights], float, T | None]]:
    """Renders the views' viewpoints once per patch window (the models usually share one) on the render
    thread, upright (`Renderer.render_upright`: whoever takes them turns them into templates). The future
    gives the renders by window, the seconds the render thread spent, and what `then` made of them there
    (called on the render thread as soon as they are done, to hand them on at once)."""

    def job(renderer: Renderer) -> tuple[dict[float, Uprights], float, T | None]:
        t0, out, own = time.perf_counter(), {}, renderer.window_mm
        m = mesh.result() if isinstance(mesh, Future) else mesh
        try:
            for w in sorted(windows):
                renderer.window_mm = w
                out[w] = renderer.render_upright(m, views)
        finally:
            renderer.window_mm = own
        seconds = time.perf_counter() - t0
        return out, seconds, None if then is None else then(out)

    return worker.submit(job)


def decimated(worker: RenderWorker, mesh: trimesh.Trimesh) -> Future[trimesh.Trimesh]:
    """`mesh` at the renderer's level of detail, decimated on the render thread (once per registration,
    not per chunk)."""

    def job(renderer: Renderer) -> trimesh.Trimesh:
        return simplify(mesh, renderer.max_faces) if len(mesh.faces) > renderer.max_faces else mesh

    return worker.submit(job)


def embed_templates(
    embedder: Embedder,
    rendered: Mapping[float, Templates],
    keep: Sequence[int] | None = None,
    *,
    local_features: bool = True,
    window_mm: float | None = None,
) -> TemplateSet:
    """Descriptors of rendered templates (those at `keep`, default all) with one model, rendered through
    `window_mm` (the object's window, `index.templates.windows`; None: the model's).
    `local_features`: also the local features of a model that has them, with each template's silhouette
    and relief from its depth (what the service's re-ranking compares); False: the descriptors alone
    (what a ranking by descriptor distance needs: the paper's protocols, whose templates may carry no
    depth)."""
    window = embedder.info.window_mm if window_mm is None else window_mm
    t = rendered[window]
    idx = np.arange(len(t.views)) if keep is None else np.asarray(keep, int)
    rgb = t.rgb[idx] if embedder.modality in ("rgb", "rgbd") else None
    depth = t.depth[idx] if embedder.modality in ("depth", "rgbd") else None
    views = [t.views[i] for i in idx]
    nominal = np.array([v.distance for v in views])
    desc = embedder.embed_patches(  # zeros: background
        rgb, depth, nominal, fill=False, window_mm=window, batch=EMBED_BATCH
    )
    poses = np.array([(v.azimuth, v.elevation, v.inplane) for v in views], np.float32).reshape(-1, 3)
    if not (local_features and embedder.has_local):
        return TemplateSet(poses, desc)
    # local features of the upright templates only: the service turns the query to a candidate's roll
    up = np.flatnonzero(np.abs(poses[:, 2]) < 1e-3)
    local = embedder.embed_patches(
        None if rgb is None else rgb[up],
        None if depth is None else depth[up],
        nominal[up],
        False,
        local=True,
        window_mm=window,
        batch=EMBED_BATCH,
    )
    # where each template's object is: the re-ranking compares the cells it covers (`index.features.local`)
    # and the shape depth sees there, for queries with depth: stored for every model with local features,
    # since the RGB-D model takes the rgb model's templates (`template_twins`); 512 bytes a viewpoint
    local = with_silhouettes(local, t.depth[idx][up], embedder.local_grid)
    local = with_relief(local, t.depth[idx][up], nominal[up], embedder.local_grid, window)
    return TemplateSet(poses, desc, up, local)


@dataclass(frozen=True)
class _Part:
    """What one embedding job made: a model's templates of some views of a chunk, whether any of them
    shows the object, and when the job ran (perf_counter seconds)."""

    templates: TemplateSet
    visible: bool
    start: float
    end: float


def _embed_part(
    embedder: Embedder, uprights: Uprights, keep: Sequence[int], window_mm: float | None
) -> _Part:
    """The views at `keep` turned from their renders and embedded by one model."""
    t0 = time.perf_counter()
    t = uprights.templates(keep, colour=embedder.modality != "depth")
    ts = embed_templates(embedder, {uprights.window_mm: t}, window_mm=window_mm)
    return _Part(ts, t.visible, t0, time.perf_counter())


def _concatenate(parts: Sequence[TemplateSet]) -> TemplateSet:
    """One set from the sets of consecutive chunks of views."""
    starts = np.cumsum([0] + [len(p.poses) for p in parts[:-1]])
    has_local = all(p.local_rows is not None and p.local is not None for p in parts)
    # a chunk without an upright view has no local rows (and its empty array not their width): left out
    local = [
        (p, s) for p, s in zip(parts, starts, strict=True) if p.local_rows is not None and len(p.local_rows)
    ]
    local = local or [(parts[0], 0)]
    return TemplateSet(
        np.concatenate([p.poses for p in parts]),
        np.concatenate([p.descriptors for p in parts]),
        np.concatenate([p.local_rows + s for p, s in local]) if has_local else None,
        np.concatenate([p.local for p, _ in local]) if has_local else None,
    )


def make_templates(
    worker: RenderWorker,
    embedders: Mapping[str, Embedder],
    mesh: trimesh.Trimesh | Future[trimesh.Trimesh],
    views: Mapping[str, list[View]],
    pool: ThreadPoolExecutor | None = None,
    chunks: int = CHUNKS,
    progress: Progress | None = None,
    window_mm: float | None = None,
) -> tuple[dict[str, TemplateSet], dict[str, float], np.ndarray]:
    """Every model's templates of `mesh` from its `views` through `window_mm` (the object's window; None:
    each model's own), seconds spent rendering and embedding, and each viewpoint's surface offset
    (`index.templates.surface.template_offsets`, rows of azimuth, elevation, mm). `mesh` may be a future of it
    already at the renderer's level of detail (`decimated`); else it is decimated here.

    The union of the views goes to the render thread once, in `chunks` (whole viewpoints each). A chunk's
    renders are handed to `pool` (serially without one) as soon as they are done, by the render thread
    itself, so the render of the next chunk and the embedding of this one never wait for each other: each
    model's views of it in halves (with a pool of two, one model's templates use both cores), each half
    turned from the upright renders and embedded in one job."""
    light = mesh if isinstance(mesh, Future) else decimated(worker, mesh)
    windows = {e.info.window_mm for e in embedders.values()} if window_mm is None else {window_mm}
    groups = _viewpoints(views)
    per = max(1, int(np.ceil(len(groups) / chunks)))
    wanted = {m: {(v.azimuth, v.elevation, v.inplane, v.distance) for v in vs} for m, vs in views.items()}
    twins = template_twins(embedders)
    submit = _now if pool is None else pool.submit
    halves = 1 if pool is None else 2

    def window_of(m: str) -> float:
        return embedders[m].info.window_mm if window_mm is None else window_mm

    def schedule(rendered: Mapping[float, Uprights]) -> list[tuple[str, Future[_Part]]]:
        """A chunk's embedding jobs, submitted: each model's own views of it (a twin takes its source's)."""
        chunk = next(iter(rendered.values())).views
        keep = {
            m: [
                i for i, v in enumerate(chunk) if (v.azimuth, v.elevation, v.inplane, v.distance) in wanted[m]
            ]
            for m in embedders
        }
        own = [m for m in embedders if not (m in twins and keep[m] == keep[twins[m]])]
        return [
            (m, submit(_embed_part, embedders[m], rendered[window_of(m)], part, window_mm))
            for m in own
            for part in _halves(keep[m], halves)
        ]

    chunked = [[v for g in groups[i : i + per] for v in g] for i in range(0, len(groups), per)]
    renders = [
        render_templates(worker, light, vs, windows, None if pool is None else schedule) for vs in chunked
    ]
    parts: dict[str, list[TemplateSet]] = {m: [] for m in embedders}
    seconds = {"render": 0.0, "embed": 0.0}
    ran: list[tuple[float, float]] = []  # when each embedding job ran
    visible = False
    offsets = []
    total, done_views = sum(len(g) for g in groups), 0
    try:
        for fut, chunk in zip(renders, chunked, strict=True):
            if progress:
                progress("render", done_views, total)
            rendered, render_s, jobs = fut.result()
            seconds["render"] += render_s
            if progress:
                progress("embed", done_views, total)
            jobs = schedule(rendered) if jobs is None else jobs
            t = rendered[min(rendered)]
            up = [i for i, v in enumerate(chunk) if abs(v.inplane) < 1e-3]
            offsets.append(template_offsets(t.templates(up).depth, [chunk[i] for i in up], t.window_mm))
            done = [(m, f.result()) for m, f in jobs]
            ran += [(p.start, p.end) for _, p in done]
            seen = {window_of(m): False for m, _ in done}
            for m, p in done:
                seen[window_of(m)] |= p.visible
            visible = visible or all(seen.values())
            sets = {m: _concatenate([p.templates for n, p in done if n == m]) for m in dict(done)}
            for m in embedders:
                parts[m].append(sets[m] if m in sets else sets[twins[m]])
            done_views += len(chunk)
    except BaseException:
        for fut in renders:  # what has not started yet need not run
            fut.cancel()
        raise
    seconds["embed"] = _covered(ran)
    if not visible:
        raise MeshError(INVISIBLE)
    out = {m: _concatenate(ps) for m, ps in parts.items()}
    return out, seconds, np.concatenate(offsets)


def _now(fn: Callable[..., T], *args: object) -> Future[T]:
    """`fn(*args)` run here and now, as a done future (`make_templates` without a pool)."""
    fut: Future[T] = Future()
    try:
        fut.set_result(fn(*args))
    except Exception as e:
        fut.set_exception(e)
    return fut


def _covered(spans: Sequence[tuple[float, float]]) -> float:
    """Seconds within at least one of the (start, end) spans."""
    out, reach = 0.0, -np.inf
    for a, b in sorted(spans):
        if b > reach:
            out += b - max(a, reach)
            reach = b
    return out


def template_twins(embedders: Mapping[str, Embedder]) -> dict[str, str]:
    """Models whose templates another model of the set makes already (`Embedder.same_templates`: the
    RGB-D model that is the rgb network with its mask from depth): model -> the model it takes them from.
    Measured (`posedesc bench`, registration): embedding was most of a registration's time."""
    out: dict[str, str] = {}
    names = sorted(embedders)
    for i, m in enumerate(names):
        for src in names[:i]:
            if src not in out and embedders[src].same_templates(embedders[m]):
                out[m] = src
                break
    return out


def _halves(keep: Sequence[int], n: int) -> list[list[int]]:
    """`keep` in n consecutive parts (whole, when n is 1 or it is short)."""
    keep = list(keep)
    if n <= 1 or len(keep) < 2 * n:
        return [keep]
    cut = int(np.ceil(len(keep) / n))
    return [keep[i : i + cut] for i in range(0, len(keep), cut)]


def register(
    mesh: trimesh.Trimesh,
    name: str,
    symmetry: str,
    *,
    worker: RenderWorker,
    embedders: Mapping[str, Embedder],
    store: TemplateStore,
    cfg: TemplateConfig = TemplateConfig(),
    pool: ThreadPoolExecutor | None = None,
    extra: Mapping[str, object] | None = None,
    progress: Progress | None = None,
    viewpoints: str | None = None,
) -> Registration:
    """Adds `mesh` (mm) under `name` to every model's store, through the window its diameter asks for
    (`index.templates.windows`), with `symmetry` (or, "auto", the one `index.geometry.shape_symmetry.resolve`
    finds), from `viewpoints` (`index.templates.viewpoints.VIEWPOINTS`; None: `cfg`'s); raises MeshError
    when it cannot be used. `progress`, when given, is told how far it is (`Progress`)."""
    t0 = time.perf_counter()
    light = decimated(worker, mesh)  # meanwhile, the diameter that decides the views
    size = diameter(mesh)
    try:
        chosen = resolve(mesh, symmetry, size)
        whole = vp.whole_sphere(viewpoints, cfg.whole or (cfg.whole_shape_only and not chosen.textured))
    except ValueError as e:
        raise MeshError(str(e)) from None
    symmetry = chosen.symmetry
    model_window = min(e.info.window_mm for e in embedders.values())
    window = window_class(size, model_window)
    views = model_views(symmetry, replace(cfg.through(window, model_window), whole=whole), embedders)
    sets, timings, offsets = make_templates(
        worker, embedders, light, views, pool, progress=progress, window_mm=window
    )
    t1 = time.perf_counter()
    stored = sum(len(ts.poses) for ts in sets.values())
    if progress:
        progress("store", 0, stored)
    glb = mesh.export(file_type="glb")  # kept so templates can be made again when a model changes
    assert isinstance(glb, bytes)  # glb is binary
    extra = {
        **(extra or {}),
        SURFACE_KEY: np.round(offsets, 2).tolist(),
        WINDOW_KEY: window,
        DIAMETER_KEY: round(size, 1),
        TEXTURED_KEY: chosen.textured,
        SYMMETRY_FROM_KEY: chosen.source,
        vp.VIEWPOINTS_KEY: "sphere" if whole else "upper",
    }
    record = store.add_object(name, symmetry, sets, faces=len(mesh.faces), mesh=glb, extra=extra)
    t2 = time.perf_counter()
    if progress:
        progress("store", stored, stored)
    # render and embed overlap (chunks), so they add up to more than the time until the last descriptor
    timings.update(store=t2 - t1, total=t2 - t0)
    log.info("registered %s: %s", name, {k: round(v, 3) for k, v in timings.items()})
    return Registration(record, timings)


def reembed(
    store: TemplateStore,
    worker: RenderWorker,
    embedders: Mapping[str, Embedder],
    cfg: TemplateConfig = TemplateConfig(),
    pool: ThreadPoolExecutor | None = None,
) -> int:
    """Makes the templates that objects lack for some model (a new or changed model) from their stored
    meshes; one transaction per object and model. Returns how many (object, model) pairs it made."""
    todo: dict[int, list[str]] = {}
    for m, oids in store.missing().items():
        for oid in oids:
            todo.setdefault(oid, []).append(m)
    done = 0
    for oid, models in todo.items():
        rec = store.snapshot.objects.get(oid)
        glb = store.mesh_bytes(oid)
        if rec is None or glb is None:
            continue
        mesh = load_mesh(glb, file_type="glb", max_faces=None)
        subset = {m: embedders[m] for m in models}
        model_window = min(e.info.window_mm for e in subset.values())
        window = object_window(rec.extra, model_window) if WINDOW_KEY in rec.extra else None
        through = replace(
            cfg.through(window or model_window, model_window), whole=vp.recorded_whole(rec.extra)
        )
        views = model_views(rec.symmetry, through, subset)
        sets, _, _ = make_templates(worker, subset, mesh, views, pool, window_mm=window)
        try:
            for m, ts in sets.items():
                store.add_templates(oid, m, ts)
                done += 1
        except KeyError:  # removed meanwhile
            continue
        log.info("made %s templates again for %s", "/".join(models), rec.name)
    return done
