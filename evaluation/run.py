"""One evaluation: register every object, cut the test patches, retrieve the 22 nearest templates with
each method, score them with the paper's metric. Everything the report and the pictures need is kept
on the returned `Evaluation`."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from evaluation.metric import K_MAX, Poses, accuracy, neighbour_errors, pose_errors, same_object
from evaluation.samples import Samples, needs_synthetic, real_samples, select_instances, synthetic_samples
from evaluation.templates import RenderedTemplates, full_inplane, object_views, render_templates
from index.bop import BopDataset
from index.embed import Embedder

METHODS = ("ours", "hog", "linemod")
#: Test patches per picture of descriptor distance against pose angle (all templates of their object).
HISTOGRAM_SAMPLES = 150


@dataclass
class Config:
    dataset: Path
    model: Path
    modality: str
    scene: int = 2
    min_visib: float = 0.5
    protocol: str = "paper"
    methods: tuple[str, ...] = METHODS
    unseen: tuple[int, ...] = ()
    frames: Sequence[int] | None = None  # None: every frame of the scene
    objects: Sequence[int] | None = None  # None: every object of the dataset
    inplane_step: float = 20.0  # full protocol: in-plane variants of every template, degrees apart
    synthetic: bool | None = None  # None: synthetic scenes only when the dataset lacks the images
    linemod_threshold: float = 50.0
    seed: int = 0


@dataclass
class MethodResult:
    """Retrieval by one method. neighbours (N, K) template indices (-1: none); scores (N, K) distances
    (LineMOD: 100 - similarity), nearest first; errors (N, K) degrees (wrong object 180); same (N, K)."""

    neighbours: np.ndarray
    scores: np.ndarray
    errors: np.ndarray
    same: np.ndarray
    separation: np.ndarray  # (N,) nearest other-object / nearest same-object distance (nan: undefined)
    angle_distance: np.ndarray  # (M, 2) pose angle vs distance, same-object templates of some patches
    seconds: float


@dataclass
class Evaluation:
    config: Config
    samples: Samples
    templates: RenderedTemplates
    symmetries: dict[int, object]
    results: dict[str, MethodResult] = field(default_factory=dict)
    descriptors: dict[str, np.ndarray] = field(default_factory=dict)  # "templates" / "samples" (ours)
    seconds: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def summary(self, ks: Sequence[int] = range(1, K_MAX + 1)) -> dict:
        """The JSON report (the contract of issue 5, plus what the run was)."""
        c, s = self.config, self.samples
        out: dict = {
            "modality": c.modality,
            "protocol": c.protocol,
            "n_samples": len(s),
            "methods": {m: accuracy(r.errors, r.same, ks) for m, r in self.results.items()},
            "per_object": {},
            "dataset": str(c.dataset),
            "scene": c.scene,
            "min_visib": c.min_visib,
            "test_data": s.source,
            "frames": sorted({int(f) for f in s.frame_ids}),
            "objects": sorted({int(o) for o in np.unique(self.templates.obj_ids)}),
            "unseen": list(c.unseen),
            "n_templates": len(self.templates),
            "model": str(c.model),
            "seconds": {k: round(v, 2) for k, v in self.seconds.items()},
            "notes": self.notes,
        }
        for obj in sorted({int(o) for o in s.obj_ids}):
            m = s.obj_ids == obj
            out["per_object"][str(obj)] = {
                name: accuracy(r.errors[m], r.same[m], ks) for name, r in self.results.items()
            }
            out["per_object"][str(obj)]["n_samples"] = int(m.sum())
        if c.unseen:
            for label, group in (("seen", False), ("unseen", True)):
                m = np.isin(s.obj_ids, c.unseen) == group
                out[f"{label}_objects"] = {
                    name: accuracy(r.errors[m], r.same[m], ks) for name, r in self.results.items()
                }
                out[f"{label}_objects"]["n_samples"] = int(m.sum())
        return out


def _bar(total: int, desc: str, unit: str = "patch") -> tqdm:
    return tqdm(total=total, desc=desc, unit=unit, disable=None, leave=False)


def evaluate(cfg: Config, embedder: Embedder | None = None) -> Evaluation:
    """Runs every method of `cfg.methods` on the same test patches and templates."""
    if unknown := set(cfg.methods) - set(METHODS):
        raise ValueError(f"unknown methods {sorted(unknown)}; use some of {', '.join(METHODS)}")
    dataset = BopDataset(cfg.dataset)
    embedder = embedder or Embedder(cfg.model, threads=2)
    spec = embedder.info.spec
    obj_ids = list(cfg.objects) if cfg.objects else dataset.obj_ids
    seconds: dict[str, float] = {}
    notes: list[str] = []

    t0 = time.perf_counter()
    instances = select_instances(dataset, cfg.scene, cfg.min_visib, cfg.frames, obj_ids)
    if not instances:
        raise ValueError(
            f"{cfg.dataset}: no instance of scene {cfg.scene} with visible fraction ≥ {cfg.min_visib} "
            "in the frames and objects asked for"
        )
    rectify = cfg.protocol == "paper"
    synthetic = needs_synthetic(cfg.modality, instances) if cfg.synthetic is None else cfg.synthetic
    with _bar(len(instances), "test patches") as bar:
        if synthetic:
            samples = synthetic_samples(
                dataset, instances, cfg.modality, spec, rectify, cfg.seed, progress=bar.update
            )
            notes.append(
                "test patches from synthetic scenes: the annotated objects rendered at their annotated "
                "poses with the frame's camera, on random backgrounds, through the sensor model"
            )
        else:
            samples = real_samples(instances, cfg.modality, spec, rectify, progress=bar.update)
    seconds["test_patches"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    meshes = {o: dataset.mesh(o) for o in obj_ids}
    symmetries = {o: dataset.symmetry(o) for o in obj_ids}
    inplane = full_inplane(cfg.inplane_step) if cfg.protocol == "full" else None
    n_views = sum(len(object_views(symmetries[o], inplane)) for o in obj_ids)
    with _bar(n_views, "render templates", "template") as bar:
        templates = render_templates(
            meshes, symmetries, cfg.modality, spec.window_mm, inplane, progress=bar.update
        )
    seconds["render_templates"] = time.perf_counter() - t0

    ev = Evaluation(cfg, samples, templates, symmetries, seconds=seconds)
    ev.notes = notes
    t_poses, s_poses = Poses.of(templates.views), Poses.of(samples.views)
    rng = np.random.default_rng(cfg.seed)
    hist_idx = rng.choice(len(samples), min(HISTOGRAM_SAMPLES, len(samples)), replace=False)

    retrieve = {"ours": _ours, "hog": _hog, "linemod": _linemod}
    for name in cfg.methods:
        t0 = time.perf_counter()
        neighbours, scores, sep, lookup = retrieve[name](ev, embedder)
        errors = neighbour_errors(
            neighbours, templates.obj_ids, t_poses, samples.obj_ids, s_poses, ev.symmetries, cfg.protocol
        )
        same = same_object(neighbours, templates.obj_ids, samples.obj_ids)
        pairs = _angle_distance(lookup, hist_idx, ev, t_poses, s_poses)
        ev.results[name] = MethodResult(
            neighbours, scores, errors, same, sep, pairs, time.perf_counter() - t0
        )
        seconds[name] = ev.results[name].seconds
    return ev


def _ours(ev: Evaluation, embedder: Embedder):
    """Our descriptors: templates embedded by the service's own `index.register.embed_templates`, test
    patches with sensor holes filled; exact nearest neighbours."""
    from evaluation.ours import distances, embed, nearest
    from index.register import embed_templates

    t, s = ev.templates, ev.samples
    t_desc = np.zeros((len(t), embedder.dim), np.float32)
    with _bar(len(t), "ours: templates", "template") as bar:
        for obj in np.unique(t.obj_ids):
            idx = t.of(int(obj))
            t_desc[idx] = embed_templates(embedder, {t.window_mm: t.object_templates(int(obj))}).descriptors
            bar.update(len(idx))
    s_desc = embed(embedder, s.rgb, s.depth, _distances(s), True)
    ev.descriptors = {"templates": t_desc, "samples": s_desc}
    dist = distances(s_desc, t_desc)
    neighbours, scores = nearest(dist, K_MAX)
    return neighbours, scores, _separation(dist, t.obj_ids, s.obj_ids), lambda i, idx: dist[i, idx]


def _hog(ev: Evaluation, embedder: Embedder):
    """HOG on the same network inputs; dot-product similarity ranked as the distance sqrt(2 - 2 dot)."""
    from evaluation.hog import hog_descriptors
    from evaluation.ours import nearest

    t, s, m, w = ev.templates, ev.samples, ev.config.modality, embedder.info.window_mm
    with _bar(len(t), "hog: templates", "template") as bar:
        t_desc = hog_descriptors(m, t.rgb, t.depth, _template_distances(t), w, False, progress=bar.update)
    s_desc = hog_descriptors(m, s.rgb, s.depth, _distances(s), w, True)
    dist = _hog_distances(s_desc, t_desc)
    neighbours, scores = nearest(dist, K_MAX)
    return neighbours, scores, _separation(dist, t.obj_ids, s.obj_ids), lambda i, idx: dist[i, idx]


def _linemod(ev: Evaluation, embedder: Embedder):
    """cv2.linemod over the same templates; each patch's best score per template."""
    from evaluation.linemod import LineModIndex, top_k

    t, s, spec = ev.templates, ev.samples, embedder.info.spec
    index = LineModIndex(ev.config.modality, spec.window_mm, spec.size, ev.config.linemod_threshold)
    with _bar(len(t), "linemod: templates", "template") as bar:
        index.add(t.obj_ids, t.rgb, t.depth, t.mask, _template_distances(t), progress=bar.update)
    if index.skipped:
        ev.notes.append(
            f"LineMOD could not extract enough features from {index.skipped} of {len(t)} templates; "
            "they are missing from its template set"
        )
    sims = []
    with _bar(len(s), "linemod: match") as bar:
        for i in range(len(s)):
            rgb = None if s.rgb is None else s.rgb[i]
            depth = None if s.depth is None else s.depth[i]
            sims.append(index.similarities(rgb, depth, s.views[i].distance))
            bar.update()
    ranked = [top_k(sim, K_MAX) for sim in sims]
    neighbours = np.stack([r[0] for r in ranked])
    scores = np.where(neighbours >= 0, 100.0 - np.stack([r[1] for r in ranked]), np.nan)

    def lookup(i: int, idx: np.ndarray) -> np.ndarray:
        return np.array([100.0 - sims[i].get(int(j), np.nan) for j in idx])

    return neighbours, scores, _linemod_separation(sims, t.obj_ids, s.obj_ids), lookup


def _template_distances(templates: RenderedTemplates) -> np.ndarray:
    return np.array([v.distance for v in templates.views])


def _distances(samples: Samples) -> np.ndarray:
    return np.array([v.distance for v in samples.views])


def _hog_distances(queries: np.ndarray, templates: np.ndarray, chunk: int = 64) -> np.ndarray:
    """HOG similarity is the dot product of unit vectors; as a distance: sqrt(2 - 2 dot). Shape: (N, T)."""
    t = templates.astype(np.float32)
    out = np.zeros((len(queries), len(t)), np.float32)
    for lo in range(0, len(queries), chunk):
        dot = queries[lo : lo + chunk].astype(np.float32) @ t.T
        out[lo : lo + chunk] = np.sqrt(np.maximum(2.0 - 2.0 * dot, 0.0))
    return out


def _separation(dist: np.ndarray, template_obj: np.ndarray, sample_obj: np.ndarray) -> np.ndarray:
    """Per patch: distance to the nearest template of another object over distance to the nearest
    template of its own object (> 1: the objects are told apart)."""
    own = template_obj[None, :] == sample_obj[:, None]
    d_own = np.where(own, dist, np.inf).min(axis=1)
    d_other = np.where(~own, dist, np.inf).min(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = d_other / d_own
    return np.where(np.isfinite(ratio), ratio, np.nan)


def _linemod_separation(sims: list[dict[int, float]], template_obj, sample_obj) -> np.ndarray:
    """As `_separation`, with 100 - similarity as the distance, over the templates that matched."""
    out = np.full(len(sims), np.nan)
    for i, s in enumerate(sims):
        own = [100.0 - v for t, v in s.items() if template_obj[t] == sample_obj[i]]
        other = [100.0 - v for t, v in s.items() if template_obj[t] != sample_obj[i]]
        if own and other and min(own) > 0:
            out[i] = min(other) / min(own)
    return out


def _angle_distance(lookup, hist_idx, ev: Evaluation, t_poses: Poses, s_poses: Poses) -> np.ndarray:
    """(pose angle, distance) for every template of the patch's own object, for the patches `hist_idx`."""
    rows = []
    for i in hist_idx:
        obj = int(ev.samples.obj_ids[i])
        idx = ev.templates.of(obj)
        angles = pose_errors(t_poses.take(idx), s_poses.take([i]), ev.symmetries[obj], ev.config.protocol)
        d = lookup(i, idx)
        ok = np.isfinite(d)
        rows.append(np.stack([angles[ok], d[ok]], axis=1))
    return np.concatenate(rows) if rows else np.zeros((0, 2))
