"""Registering an object, the one code path of the API, `posedesc build-index`, the evaluation and the
benchmarks: mesh -> renders of every template view (on the render thread) -> patches -> descriptors of
every model -> the store, in one transaction for all models.

Template views: the paper's level-3 half-sphere (301 viewpoints) at 400 mm, times the in-plane steps.
The default has no in-plane variants. Measured with `.venv/bin/python benchmarks/serving.py` (2 cores
shared with other work, three models, a 21.8k-face mesh): 301 templates per model take render 2.5 s and
embed 1.0 s, overlapping, 2.8 s in all (since then, on an idle machine: render 1.2 s, all 1.35 s; `posedesc bench`); in-plane variants
cost no render but multiply embedding: +-45 in 45 steps (903) 4.4 s, 15 steps (2107) 7.6 s, against a
target of ~2 s per registration. A service that must recognise rolled objects sets a step (settings).

Symmetric objects do not need every viewpoint: the views of a "180" object from azimuth a and a + 180
are the same picture, so only azimuths in [0, 180) are kept; a "full" object looks the same from every
azimuth at one elevation, and the icosphere is 5-fold symmetric about z, so the wedge [0, 72) holds
every elevation of the set: a fifth of the templates with no loss of elevation resolution. The answer
for such an object gives the matched template's azimuth, one of the equivalent ones.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import trimesh

from index.embed import Embedder
from index.mesh import MeshError, load_mesh, simplify
from index.pose import View
from index.render import Renderer, RenderWorker, Templates
from index.store import ObjectRecord, Store, TemplateSet
from index.symmetry import SYMMETRIES
from index.viewpoints import inplane_steps
from index.viewpoints import template_views as all_template_views

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TemplateConfig:
    level: int = 3  # icosphere subdivisions: 3 = the paper's 301 template viewpoints
    inplane_step: float = 0.0  # degrees; 0 = no in-plane variants (see the module docstring)
    inplane_max: float = 45.0  # variants span +-this
    distance_mm: float = 400.0  # render distance (LineMOD's); patches are metric, so it barely matters


@dataclass
class Registration:
    """What a registration did: the object's record and seconds spent in render / embed / store."""

    record: ObjectRecord
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def template_views(symmetry: str, cfg: TemplateConfig = TemplateConfig()) -> list[View]:
    """The template views of an object with this symmetry (viewpoint-major)."""
    if symmetry not in SYMMETRIES:
        raise MeshError(f"unknown symmetry {symmetry!r}; use one of {', '.join(SYMMETRIES)}")
    views = all_template_views(cfg.level, inplane_steps(cfg.inplane_step, cfg.inplane_max), cfg.distance_mm)
    if symmetry == "none":
        return views
    wedge = {"180": 180.0, "full": 72.0}[symmetry]
    # +1e-6: a vertex on a wedge's edge may come out of arctan2 a hair below it (359.9999... for 0)
    return [v for v in views if (v.azimuth + 1e-6) % 360.0 < wedge]


def render_templates(
    worker: RenderWorker,
    mesh: trimesh.Trimesh | Future[trimesh.Trimesh],
    views: list[View],
    windows: set[float],
) -> Future[tuple[dict[float, Templates], float]]:
    """Renders the views once per patch window (the models usually share one) on the render thread.
    The future gives the templates by window and the seconds the render thread spent."""

    def job(renderer: Renderer) -> tuple[dict[float, Templates], float]:
        t0, out, own = time.perf_counter(), {}, renderer.window_mm
        m = mesh.result() if isinstance(mesh, Future) else mesh
        try:
            for w in sorted(windows):
                renderer.window_mm = w
                out[w] = renderer.render(m, views)
        finally:
            renderer.window_mm = own
        return out, time.perf_counter() - t0

    return worker.submit(job)


def embed_templates(embedder: Embedder, rendered: Mapping[float, Templates]) -> TemplateSet:
    """Descriptors of rendered templates with one model."""
    t = rendered[embedder.info.window_mm]
    rgb = t.rgb if embedder.modality in ("rgb", "rgbd") else None
    depth = t.depth if embedder.modality in ("depth", "rgbd") else None
    nominal = np.array([v.distance for v in t.views])
    desc = embedder.embed_patches(rgb, depth, nominal, fill=False)  # a render's zeros are background
    poses = np.array([(v.azimuth, v.elevation, v.inplane) for v in t.views], np.float32)
    return TemplateSet(poses, desc)


def make_templates(
    worker: RenderWorker,
    embedders: Mapping[str, Embedder],
    mesh: trimesh.Trimesh,
    views: list[View],
    pool: ThreadPoolExecutor | None = None,
    chunks: int = 4,
) -> tuple[dict[str, TemplateSet], dict[str, float]]:
    """Every model's templates of `mesh` from `views`, and seconds spent rendering and embedding.

    The views go to the render thread in `chunks` (whole viewpoints each); a chunk is embedded while
    the next renders, and the models of a chunk run side by side on `pool` (serially without one).
    The mesh is decimated once (on the render thread, to the renderer's level of detail), not per chunk."""

    def decimate(renderer: Renderer) -> trimesh.Trimesh:
        return simplify(mesh, renderer.max_faces) if len(mesh.faces) > renderer.max_faces else mesh

    light = worker.submit(decimate)
    windows = {e.info.window_mm for e in embedders.values()}
    per_viewpoint = max(1, len(views) // max(1, len({(v.azimuth, v.elevation) for v in views})))
    step = per_viewpoint * max(1, int(np.ceil(len(views) / per_viewpoint / chunks)))
    renders = [
        render_templates(worker, light, views[i : i + step], windows) for i in range(0, len(views), step)
    ]
    parts: dict[str, list[TemplateSet]] = {m: [] for m in embedders}
    seconds = {"render": 0.0, "embed": 0.0}
    visible = False
    for fut in renders:
        rendered, render_s = fut.result()
        seconds["render"] += render_s
        visible = visible or _visible(rendered)
        t0 = time.perf_counter()
        if pool is None:
            sets = {m: embed_templates(e, rendered) for m, e in embedders.items()}
        else:
            futures = {m: pool.submit(embed_templates, e, rendered) for m, e in embedders.items()}
            sets = {m: f.result() for m, f in futures.items()}
        seconds["embed"] += time.perf_counter() - t0
        for m, ts in sets.items():
            parts[m].append(ts)
    if not visible:
        raise MeshError("the object is invisible in every template: check its units")
    out = {
        m: TemplateSet(np.concatenate([p.poses for p in ps]), np.concatenate([p.descriptors for p in ps]))
        for m, ps in parts.items()
    }
    return out, seconds


def _visible(rendered: Mapping[float, Templates]) -> bool:
    return all(bool((t.depth > 0).any()) for t in rendered.values())


def register(
    mesh: trimesh.Trimesh,
    name: str,
    symmetry: str,
    *,
    worker: RenderWorker,
    embedders: Mapping[str, Embedder],
    store: Store,
    cfg: TemplateConfig = TemplateConfig(),
    pool: ThreadPoolExecutor | None = None,
    extra: Mapping[str, object] | None = None,
) -> Registration:
    """Adds `mesh` (mm) under `name` to every model's store; raises MeshError when it cannot be used."""
    t0 = time.perf_counter()
    sets, timings = make_templates(worker, embedders, mesh, template_views(symmetry, cfg), pool)
    t1 = time.perf_counter()
    glb = mesh.export(file_type="glb")  # kept so templates can be made again when a model changes
    record = store.add_object(name, symmetry, sets, faces=len(mesh.faces), mesh=glb, extra=extra)
    t2 = time.perf_counter()
    # render and embed overlap (chunks), so they add up to more than the time until the last descriptor
    timings.update(store=t2 - t1, total=t2 - t0)
    log.info("registered %s: %s", name, {k: round(v, 3) for k, v in timings.items()})
    return Registration(record, timings)


def reembed(
    store: Store,
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
        sets, _ = make_templates(worker, subset, mesh, template_views(rec.symmetry, cfg), pool)
        try:
            for m, ts in sets.items():
                store.add_templates(oid, m, ts)
                done += 1
        except KeyError:  # removed meanwhile
            continue
        log.info("made %s templates again for %s", "/".join(models), rec.name)
    return done
