"""What the lifespan loads once and every request shares (`app.state.posedesc`)."""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path

import trimesh

from index.draw import MASK_FACES, DrawMesh, MeshCache
from index.features.embed import Embedder, load_models, store_keys
from index.features.objectness import OBJECTNESS_FILE, Colour, ObjectnessNet
from index.features.objectness import propose as propose_objects
from index.refine.chroma import SurfaceColours
from index.refine.files import ColourFiles
from index.store import EMBEDDED, TemplateStore, open_store
from index.store.shared_files import SharedFiles
from index.templates.mesh import load_mesh
from index.templates.register import Progress, Registration, TemplateConfig, register
from index.templates.render import RenderWorker
from service.jobs import Jobs
from service.metrics import Metrics
from service.pipeline import Pipeline
from service.pipeline.fit import CAPACITY, Shapes
from service.settings import Settings
from service.threads import limit_threads, worker_pool

log = logging.getLogger("service")


@dataclass
class AppState:
    settings: Settings
    embedders: dict[str, Embedder]
    store: TemplateStore
    worker: RenderWorker
    templates: TemplateConfig
    #: the pools below are made from `settings.threads` (service/threads.py)
    #: registrations one at a time: rendering is one thread anyway, and two cores must keep serving
    registrar: ThreadPoolExecutor = field(init=False)
    #: the models of a registration embed side by side (onnxruntime releases the GIL)
    embed_pool: ThreadPoolExecutor = field(init=False)
    #: one uploaded mesh in memory and parsed at a time: a hostile one may take ~1 GB until it is refused.
    #: Always on the same thread, so the allocator reuses that memory rather than growing another arena.
    mesh_gate: asyncio.Semaphore = field(default_factory=lambda: asyncio.Semaphore(1))
    mesh_loader: ThreadPoolExecutor = field(init=False)
    #: recognitions decoding at once (a 4096 x 4096 depth image takes ~250 MB); 2 cores serve 2 anyway
    recognition_gate: asyncio.Semaphore = field(default_factory=lambda: asyncio.Semaphore(2))
    #: where recognitions run (as many threads as the gate lets in)
    recognizer: ThreadPoolExecutor = field(init=False)
    #: where a frame's places are verified side by side (`service.detection.verify`), apart from
    #: `recognizer`, whose thread waits for them
    verifier: ThreadPoolExecutor = field(init=False)
    #: where the pose fit's models of new and stored objects are made ahead of the queries that need
    #: them (`warm`): a colour one takes seconds
    fitter: ThreadPoolExecutor = field(init=False)
    #: the meshes `POST /recognize/draw` draws, read from the store once per object (`index.draw`)
    draw_meshes: MeshCache[DrawMesh] = field(init=False)
    #: what the pose fit needs of each object, made from `draw_meshes` (`service.pipeline.fit`)
    shapes: Shapes = field(init=False)
    #: the colour fit models kept in the data dir, read back instead of made again (`index.refine.files`)
    fit_files: ColourFiles = field(init=False)
    #: each coloured object's surface colours, for the detection's colour check (`service.detection.agree`)
    surfaces: MeshCache[SurfaceColours] = field(init=False)
    #: each object's drawing mesh cut to `MASK_FACES`, for the detections' masks (`service.detection.mask`)
    mask_meshes: MeshCache[DrawMesh] = field(init=False)
    #: colour proposals for finding objects in a whole frame (`service.detection.proposals`): the objectness model
    #: of the models dir, or None without one
    colour_proposals: Colour | None = None
    jobs: Jobs = field(default_factory=Jobs)
    metrics: Metrics = field(default_factory=Metrics)
    ready: threading.Event = field(default_factory=threading.Event)
    stopping: threading.Event = field(default_factory=threading.Event)
    started: float = field(default_factory=time.time)
    startup_error: str | None = None
    #: `pipelines` and the settings and models they were built from
    _pipelines: tuple[Settings, dict[str, Embedder], dict[str, Pipeline]] | None = field(
        default=None, init=False, repr=False
    )
    _screens: tuple[Settings, dict[str, Embedder], dict[str, Pipeline]] | None = field(
        default=None, init=False, repr=False
    )

    def __post_init__(self) -> None:
        n = self.settings.threads
        self.registrar = worker_pool(1, "register", n)
        self.embed_pool = worker_pool(2, "embed", n)
        self.mesh_loader = worker_pool(1, "mesh", n)
        self.recognizer = worker_pool(2, "recognise", n)
        self.verifier = worker_pool(self.settings.detect_threads, "verify", n)
        self.fitter = worker_pool(1, "fit", n)
        self.draw_meshes = MeshCache(lambda oid: DrawMesh.from_glb(self.store.mesh_bytes(oid)))
        self.fit_files = ColourFiles(self.settings.data_dir, self._registered)
        self.shapes = Shapes(self.draw_meshes, files=self.fit_files)
        self.surfaces = MeshCache(self._surface, CAPACITY)
        self.mask_meshes = MeshCache(self._mask_mesh, CAPACITY)

    def _registered(self, object_id: int) -> float | None:
        rec = self.store.snapshot.objects.get(object_id)
        return None if rec is None else rec.created

    def remove(self, object_id: int) -> bool:
        """Removes an object from the store, and its kept fit model; False when it is not registered."""
        if not self.store.remove_object(object_id):
            return False
        self.fit_files.remove(object_id)
        return True

    def forget_deleted(self) -> None:
        """The caches of each object's meshes and models (the fit's, the colours', the masks') cut to the
        objects registered now: a deleted object's are dropped (ids are never reused)."""
        registered = set(self.store.snapshot.objects)
        self.shapes.prune(registered)
        self.surfaces.prune(registered)
        self.mask_meshes.prune(registered)

    def _mask_mesh(self, object_id: int) -> DrawMesh | None:
        mesh = self.draw_meshes.get(object_id)
        return None if mesh is None else mesh.coarse(MASK_FACES)

    def _surface(self, object_id: int) -> SurfaceColours | None:
        """An object's surface colours from its stored mesh (GLB, with its colours); None: no mesh, or none."""
        glb = self.store.mesh_bytes(object_id)
        return None if glb is None else SurfaceColours.of(load_mesh(glb, file_type="glb", max_faces=None))

    @property
    def pipelines(self) -> dict[str, Pipeline]:
        """Each model's recognition pipeline (`service.pipeline`), built once from the settings and the
        models and kept while both stay the same objects: the service never changes them, an evaluation
        swaps the settings between queries (`evaluation.openset`: with and without the re-ranking). A
        pipeline reads the store's snapshot per query, so registrations need no rebuild."""
        built = self._pipelines
        if built is None or built[0] is not self.settings or built[1] is not self.embedders:
            pipelines = {
                m: Pipeline.build(
                    self.settings, e, self.templates, self.shapes, self.metrics.failed, self.surfaces.get
                )
                for m, e in self.embedders.items()
            }
            self._pipelines = built = (self.settings, self.embedders, pipelines)
        return built[2]

    @property
    def screens(self) -> dict[str, Pipeline]:
        """Each model's screening pipeline (`service.detection`): the same stages with a shorter re-ranking
        and no roll sweep or refinement, kept as `pipelines` are."""
        built = self._screens
        if built is None or built[0] is not self.settings or built[1] is not self.embedders:
            screens = {
                m: Pipeline.screening(self.settings, e, self.templates) for m, e in self.embedders.items()
            }
            self._screens = built = (self.settings, self.embedders, screens)
        return built[2]

    def register_mesh(
        self,
        mesh: trimesh.Trimesh,
        name: str,
        symmetry: str,
        extra: Mapping[str, object] | None = None,
        progress: Progress | None = None,
        viewpoints: str | None = None,
    ) -> Registration:
        """`mesh` registered into this state's store with its renderer, models and pools, as `POST /objects`
        registers it (`index.templates.register.register`; `viewpoints`: one of
        `index.templates.viewpoints.VIEWPOINTS`, None: the settings')."""
        reg = register(
            mesh,
            name,
            symmetry,
            worker=self.worker,
            embedders=self.embedders,
            store=self.store,
            cfg=self.templates,
            pool=self.embed_pool,
            extra=extra,
            progress=progress,
            viewpoints=viewpoints,
        )
        self.warm([reg.record.object_id], {reg.record.object_id: mesh})
        return reg

    def warm(self, object_ids: Iterable[int], meshes: Mapping[int, trimesh.Trimesh] | None = None) -> None:
        """The pose fit's models of these objects (`service.pipeline.fit.Shapes`: the colour one for the rgb
        model, the depth one for a model that reads depth) made on the fit thread, ahead of the first query
        that needs them; as many as the cache keeps. Nothing with the pose fit off. `meshes`: those of
        the objects at hand (just registered), so their drawing meshes are made from them, not read back
        from the store (`DrawMesh.as_stored`). The detection's colour check's surface colours too (a model that
        reads colour), whether the pose fit is on or not."""

        def ahead(oid: int, make: Callable[..., object], *args: object) -> None:
            """`make(*args)` on the fit thread, unless the object was deleted by then: its models would be
            made for nothing, and kept until the cache dropped them."""
            self.fitter.submit(lambda: make(*args) if oid in self.store.snapshot.objects else None)

        if {"rgb", "rgbd"} & set(self.embedders):  # the detection's colour check reads colour frames
            for oid in list(object_ids)[:CAPACITY]:
                if meshes is not None and oid in meshes:
                    ahead(oid, lambda o, m: self.surfaces.put(o, SurfaceColours.of(m)), oid, meshes[oid])
                else:
                    ahead(oid, self.surfaces.get, oid)
        if self.settings.pose_fit == 0:
            return
        caches = self.shapes.needed(self.embedders)
        for oid in list(object_ids)[:CAPACITY]:
            if meshes is not None and oid in meshes:  # the fit thread takes its jobs in order: first this
                ahead(oid, lambda o, m: self.draw_meshes.put(o, DrawMesh.as_stored(m)), oid, meshes[oid])
            for cache in caches:
                ahead(oid, cache.get, oid)

    @property
    def model_names(self) -> dict[str, str]:
        return {m: e.path.stem for m, e in self.embedders.items()}


def load_state(settings: Settings, embedders: dict[str, Embedder] | None = None) -> AppState:
    """Models (those of `settings.models_dir` unless given), store and render thread; raises with a
    one-line message when something is missing."""
    limit_threads(settings.threads)  # this thread rebuilds the indexes the snapshots cannot give
    embedders = embedders or load_models(settings.models_dir, settings.threads)
    windows = {e.info.window_mm for e in embedders.values()}
    sizes = {e.info.size for e in embedders.values()}
    if len(sizes) != 1:
        raise ValueError(f"the models disagree about the patch size: {sorted(sizes)}")
    store = open_store(
        settings.store,
        settings.data_dir,
        store_keys(embedders),
        kind=settings.index_kind,
        sweep_seconds=settings.store_sweep_seconds,
        prefix=settings.store_prefix,
        ivf_min=settings.ivf_min_templates,
    )
    worker = RenderWorker(size=sizes.pop(), window_mm=min(windows))
    cfg = TemplateConfig(
        settings.level,
        settings.inplane_step,
        settings.inplane_max,
        whole=settings.viewpoints == "sphere",
        whole_shape_only=settings.viewpoints == "auto",
    )
    where = (
        settings.data_dir
        if settings.store == EMBEDDED
        else f"{settings.store} (files in {settings.data_dir})"
    )
    log.info("models %s, %d objects in %s", sorted(embedders), len(store.snapshot.objects), where)
    # behind a load balancer a job is polled on any replica: with a shared store, job states are shared files
    jobs = Jobs() if settings.store == EMBEDDED else Jobs(files=SharedFiles(settings.data_dir))
    colour = colour_proposals(objectness_path(settings), settings.detect_threads, settings.objectness_levels)
    state = AppState(settings, embedders, store, worker, cfg, jobs=jobs, colour_proposals=colour)
    # the kept fit models of objects deleted while no process served this data dir, or by other code
    state.fit_files.sweep({oid: rec.created for oid, rec in store.snapshot.objects.items()})
    return state


def objectness_path(settings: Settings) -> Path:
    """Where the service's objectness network is: `Settings.objectness_model`, else beside the models."""
    return settings.objectness_model or settings.models_dir / OBJECTNESS_FILE


def colour_proposals(path: Path, threads: int, levels: Sequence[float] | None = None) -> Colour | None:
    """The objectness model at `path` as the detection's colour proposals, run at `levels` (the frame's
    scales; None: those in the model's metadata), or None when there is none (a colour frame without a
    centre is then refused with what to send instead)."""
    if not path.is_file():
        log.warning("no objectness model at %s: colour frames need u and v", path)
        return None
    net = ObjectnessNet(path, threads)
    return partial(propose_objects, net, levels=levels or None)


def close_state(state: AppState) -> None:
    state.stopping.set()
    state.registrar.shutdown(wait=True, cancel_futures=True)  # a registration in flight finishes (atomic)
    state.mesh_loader.shutdown(wait=True, cancel_futures=True)
    state.embed_pool.shutdown(wait=True)
    state.recognizer.shutdown(wait=True)
    state.verifier.shutdown(wait=True)
    state.fitter.shutdown(wait=True, cancel_futures=True)
    state.worker.close()
    state.jobs.close()
    state.store.close()
