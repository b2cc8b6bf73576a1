"""The objects the benchmarks measure on: a few procedural shapes rendered once, turned into as many
distinct objects as a section needs, and real-looking query patches.

Rendering 1,000 meshes would take most of an hour here, so `distinct` shapes (`index.templates.shapes.random_shape`)
are rendered from the service's template views once, and object j is shape j % distinct seen through one
of 48 exact image transforms (4 quarter turns x mirror x 6 orders of the colour channels; depth follows
the geometric part). Every object then has templates of its own, as a new mesh would: the network sees
different patches, LineMOD extracts different features, and neither method's cost depends on where the
templates came from. A template's pose label is the view it was rendered from (poses do not enter
the timing).

Templates with in-plane variants (`inplane_template_sets`, the roll section) are made as registration
makes them: each viewpoint rendered once, turned about the patch centre for every in-plane angle. There
the objects are the shapes through the 12 transforms without a quarter turn (a quarter turn of a whole
turn of in-plane variants would give the same templates again, only labelled 90 degrees apart)."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import trimesh

from index.features.embed import Embedder
from index.features.local import with_relief, with_silhouettes
from index.features.patches import batch_inputs
from index.geometry.pose import View
from index.geometry.sensor import SensorModel, random_background
from index.store import TemplateSet
from index.templates.register import TemplateConfig, embed_templates, template_twins, template_views
from index.templates.render import Renderer, Templates
from index.templates.shapes import random_shape
from index.templates.viewpoints import sphere_views

PERMUTATIONS = list(itertools.permutations(range(3)))
VARIANTS = 8 * len(PERMUTATIONS)  # dihedral group of the square x channel orders
#: the variants without a quarter turn (mirror x channel orders): distinct objects with in-plane variants
TURN_FREE_VARIANTS = tuple(k for k in range(VARIANTS) if k % 4 == 0)
QUERY_VIEW = View(azimuth=37.0, elevation=33.0, inplane=0.0, distance=400.0)  # between template views


def variant(
    rgb: np.ndarray, depth: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:  # (T, S, S, 3), (T, S, S)
    """The k-th of `VARIANTS` exact transforms of a stack of patches; k = 0 is the identity."""
    turns, mirror, perm = k % 4, (k // 4) % 2, PERMUTATIONS[k // 8]
    rgb, depth = np.rot90(rgb, turns, axes=(1, 2)), np.rot90(depth, turns, axes=(1, 2))
    if mirror:
        rgb, depth = rgb[:, :, ::-1], depth[:, :, ::-1]
    return np.ascontiguousarray(rgb[..., list(perm)]), np.ascontiguousarray(depth)


def variant_inputs(x: np.ndarray, k: int, colour: bool) -> np.ndarray:
    """The network inputs (T, C, S, S) of variant k's templates from those of the identity's: a patch's
    normalisation (`index.features.patches`: per-channel mean and spread, depth relative to the central square)
    does not see quarter turns or mirroring and follows the channels' order, so the inputs transform as
    the images do. `colour`: the first three channels are RGB."""
    turns, mirror, perm = k % 4, (k // 4) % 2, PERMUTATIONS[k // 8]
    x = np.rot90(x, turns, axes=(2, 3))
    if mirror:
        x = x[:, :, :, ::-1]
    if colour:
        x = x[:, [*perm, *range(3, x.shape[1])]]
    return np.ascontiguousarray(x)


@dataclass
class ObjectSet:
    """Renders of `distinct` shapes at the template views and a query patch of shape 0 at `QUERY_VIEW`.

    rgb: (M, T, S, S, 3) uint8; depth: (M, T, S, S) mm; query_rgb (S, S, 3), query_depth (S, S): a
    render through the sensor model on a random background, as a camera would see it."""

    views: list[View]
    rgb: np.ndarray
    depth: np.ndarray
    window_mm: float
    query_rgb: np.ndarray
    query_depth: np.ndarray
    seed: int = 0
    _sets: dict[tuple[str, int], TemplateSet] = field(default_factory=dict, repr=False)

    @property
    def capacity(self) -> int:
        """How many distinct objects can be made."""
        return len(self.rgb) * VARIANTS

    @property
    def templates_per_object(self) -> int:
        return len(self.views)

    def templates(self, j: int) -> Templates:
        """Object j's templates, as the renderer would give them."""
        if not 0 <= j < self.capacity:
            raise ValueError(f"object {j}: only {self.capacity} can be made from {len(self.rgb)} shapes")
        m = len(self.rgb)
        rgb, depth = variant(self.rgb[j % m], self.depth[j % m], j // m)
        return Templates(self.views, rgb, depth, self.window_mm)

    def template_set(self, embedder: Embedder, j: int) -> TemplateSet:
        """Object j's descriptors with one model, as `index.templates.register` makes them (cached)."""
        key = (str(embedder.path), j)
        if key not in self._sets:
            self._sets[key] = embed_templates(embedder, {self.window_mm: self.templates(j)})
        return self._sets[key]

    def embed_all(self, embedder: Embedder, n: int, progress: Callable[[int], object] | None = None) -> None:
        """Descriptors of objects 0..n-1 into the cache, shape by shape: each shape's network inputs are
        made once and transformed for its variants (`variant_inputs`), as `template_set` would make them."""
        m, colour = len(self.rgb), embedder.modality in ("rgb", "rgbd")
        depth = embedder.modality in ("depth", "rgbd")
        poses = np.array([(v.azimuth, v.elevation, v.inplane) for v in self.views], np.float32)
        nominal = np.array([v.distance for v in self.views])
        for a in range(min(m, n)):
            todo = [
                k
                for k in range(VARIANTS)
                if a + m * k < n and (str(embedder.path), a + m * k) not in self._sets
            ]
            if not todo:
                continue
            base = batch_inputs(
                embedder.modality,
                self.rgb[a] if colour else None,
                self.depth[a] if depth else None,
                nominal,
                self.window_mm,
                fill=False,  # a render's zeros are background, as in `index.templates.register.embed_templates`
            )
            for k in todo:
                desc = embedder(variant_inputs(base, k, colour), batch=128)
                self._sets[(str(embedder.path), a + m * k)] = TemplateSet(poses, desc)
                if progress:
                    progress(1)

    def patches(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """n real-looking patches: templates of the shapes through the sensor model on random
        backgrounds. Shapes: (n, S, S, 3) uint8, (n, S, S) mm."""
        rng = np.random.default_rng(self.seed + 1)
        sensor = SensorModel()
        m, t = self.rgb.shape[:2]
        rgb, depth = (
            np.zeros((n, *self.rgb.shape[2:]), np.uint8),
            np.zeros((n, *self.depth.shape[2:]), np.float32),
        )
        for i in range(n):
            a, b = int(rng.integers(m)), int(rng.integers(t))
            rgb[i], depth[i] = _through_sensor(self.rgb[a, b], self.depth[a, b], rng, sensor)
        return rgb, depth


def _through_sensor(
    rgb: np.ndarray, depth: np.ndarray, rng: np.random.Generator, sensor: SensorModel
) -> tuple[np.ndarray, np.ndarray]:
    bg_rgb, bg_depth = random_background(depth.shape, rng, QUERY_VIEW.distance)
    return sensor.apply(rgb, depth, rng, bg_rgb, bg_depth)


def render_objects(
    distinct: int,
    size: int = 64,
    window_mm: float = 200.0,
    level: int = 3,
    seed: int = 0,
    progress: Callable[[int], object] | None = None,
) -> ObjectSet:
    """Renders `distinct` random shapes from the service's template views (icosphere `level`)."""
    rng = np.random.default_rng(seed)
    meshes = [random_shape(rng) for _ in range(distinct)]  # as `shapes(distinct, seed)`
    views = template_views("none", TemplateConfig(level=level))
    renderer = Renderer(size=size, window_mm=window_mm)
    try:
        rendered = [renderer.render(m, views, progress=progress) for m in meshes]
        query = renderer.render(meshes[0], [QUERY_VIEW])
    finally:
        renderer.close()
    q_rgb, q_depth = _through_sensor(query.rgb[0], query.depth[0], rng, SensorModel())
    return ObjectSet(
        views=views,
        rgb=np.stack([t.rgb for t in rendered]),
        depth=np.stack([t.depth for t in rendered]),
        window_mm=window_mm,
        query_rgb=q_rgb,
        query_depth=q_depth,
        seed=seed,
    )


def shapes(count: int, seed: int = 0) -> list[trimesh.Trimesh]:
    """The first `count` shapes of `render_objects(..., seed)`: shape 0 is its query's."""
    rng = np.random.default_rng(seed)
    return [random_shape(rng) for _ in range(count)]


def inplane_template_sets(
    n: int,
    models: Mapping[str, tuple[Embedder, Sequence[float] | np.ndarray]],
    level: int = 3,
    size: int = 64,
    window_mm: float = 200.0,
    seed: int = 0,
    progress: Callable[[int], object] | None = None,
) -> dict[str, list[TemplateSet]]:
    """Templates of objects 0..n-1 for every model in `models` (a name -> its embedder and its in-plane
    angles, degrees), viewpoint-major as `index.templates.register` orders them: each model's views are
    `index.templates.viewpoints.sphere_views(level, its angles)`, and each viewpoint is rendered once for the
    union of the angles and turned (`Renderer.render`, the registration's renderer). Object j is shape
    j % m (`shapes(m, seed)`, m = ceil(n / 12)) through transform `TURN_FREE_VARIANTS[j // m]`, applied
    to the network inputs (`variant_inputs`). Renders are kept for one shape at a time. `progress`
    counts objects x models."""
    m = -(-n // len(TURN_FREE_VARIANTS))
    angles = {name: np.round(np.asarray(a, float), 6) for name, (_, a) in models.items()}
    union = np.unique(np.concatenate(list(angles.values()))) if angles else np.zeros(1)
    views = sphere_views(level, union)
    inplane = np.round(np.array([v.inplane for v in views]), 6)
    out: dict[str, list[TemplateSet]] = {name: [] for name in models}
    per_shape: dict[str, list[TemplateSet]] = {}
    renderer = Renderer(size=size, window_mm=window_mm)
    # a model making another's very templates (the RGB-D model exported from the rgb run) takes them, as
    # registration does (`index.templates.register.template_twins`)
    twins = {
        m: src
        for m, src in template_twins({name: e for name, (e, _) in models.items()}).items()
        if np.array_equal(angles[m], angles[src])
    }
    try:
        for a, mesh in enumerate(shapes(m, seed)):
            t = renderer.render(mesh, views)
            for name, (e, _) in models.items():
                if name in twins:
                    continue
                keep = np.flatnonzero(np.isin(inplane, angles[name]))
                colour = e.modality in ("rgb", "rgbd")
                base = batch_inputs(
                    e.modality,
                    t.rgb[keep] if colour else None,
                    t.depth[keep] if e.modality in ("depth", "rgbd") else None,
                    np.array([views[i].distance for i in keep]),
                    window_mm,
                    fill=False,  # a render's zeros are background, as in `index.templates.register.embed_templates`
                )
                poses = np.array([(views[i].azimuth, views[i].elevation, views[i].inplane) for i in keep])
                up = np.flatnonzero(np.abs(poses[:, 2]) < 1e-3)  # local features: upright ones, as stored
                shown = (t.depth[keep[up]] > 0)[:, None].astype(np.float32)
                per_shape[name] = [
                    TemplateSet(
                        poses.astype(np.float32),
                        e(variant_inputs(base, k, colour), batch=128),
                        *(
                            (
                                up,
                                with_relief(
                                    with_silhouettes(
                                        e.local(variant_inputs(base[up], k, colour)),
                                        variant_inputs(shown, k, False)[:, 0],
                                        e.local_grid,
                                    ),
                                    variant_inputs(t.depth[keep[up]][:, None], k, False)[:, 0],
                                    np.array([views[i].distance for i in keep[up]]),
                                    e.local_grid,
                                    window_mm,
                                ),
                            )
                            if e.has_local
                            else ()
                        ),
                    )
                    for k in TURN_FREE_VARIANTS[: len(range(a, n, m))]
                ]
                if progress:
                    progress(len(per_shape[name]))
            for name in models:
                out[name].extend(per_shape[twins.get(name, name)])
                if progress and name in twins:
                    progress(len(per_shape[twins[name]]))
    finally:
        renderer.close()
    order = [a + m * v for a in range(m) for v in range(len(range(a, n, m)))]  # object id of each set
    return {name: [sets[i] for i in np.argsort(order)] for name, sets in out.items()}
