"""One evaluation: the test patches, the templates, each method's nearest answers, the paper's metric.

`--protocol service` (`evaluation.served`) is what a user of `POST /recognize` gets; `paper` and `full`
cut the test patches at the true centre and distance themselves and retrieve the 22 nearest templates
with each method (adapters: `evaluation.ours`, `hog`, `linemod`). Everything the report and the pictures
need is kept on the returned `Evaluation`."""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from evaluation import hog, linemod, ours
from evaluation.metric import K_MAX, Poses, accuracy, neighbour_errors, pose_errors, same_object
from evaluation.neighbours import Ranking
from evaluation.samples import Samples, needs_synthetic, real_samples, select_instances, synthetic_samples
from evaluation.templates import RenderedTemplates, full_inplane, object_views, render_template_set
from index.bop import BopDataset
from index.embed import Embedder
from index.symmetry import Symmetry

METHODS = ("ours", "hog", "linemod")
#: Test patches per picture of descriptor distance against pose angle (all templates of their object).
HISTOGRAM_SAMPLES = 150
SYNTHETIC_NOTE = (
    "test frames are synthetic: the annotated objects rendered at their annotated poses with the frame's "
    "camera, on random backgrounds, through the sensor model (in-distribution for our model only)"
)


@dataclass
class Config:
    dataset: Path
    model: Path
    modality: str
    scene: int = 2
    min_visib: float = 0.5
    protocol: str = "service"
    methods: tuple[str, ...] = METHODS
    unseen: tuple[int, ...] = ()
    frames: Sequence[int] | None = None  # None: every frame of the scene
    objects: Sequence[int] | None = None  # None: every object of the dataset
    #: in-plane variants of every template, degrees apart: full protocol (default 20°); service protocol:
    #: the service's setting (None: the settings' own, by default the model's metadata)
    inplane_step: float | None = None
    inplane_max: float | None = None  # service protocol: the service's setting (None: the settings')
    query_turns: int | None = None  # service protocol: the service's setting (None: the settings')
    #: True: synthetic scenes; None: only when the dataset lacks the images (the service protocol renders
    #: just the depth where only depth is missing: `evaluation.samples.served_data`)
    synthetic: bool | None = None
    linemod_threshold: float = 50.0
    #: service protocol: each frame sent black outside the instance's ground-truth visible mask (the
    #: clutter-free bound, `evaluation/masks.py`); colour only
    oracle_mask: bool = False
    #: service protocol: every frame sent again at these camera rolls, degrees (`evaluation.rolls`);
    #: empty: each frame once, as it is
    rolls: tuple[float, ...] = ()
    seed: int = 0


@dataclass
class MethodResult:
    """One method's answers. errors (N, K) degrees, wrong object 180: the viewing-direction error (paper)
    or the 3-D rotation error (full, service); same (N, K): the right object; the service protocol adds
    view_errors (N, K) and, for ours, each recognise call's milliseconds. neighbours (N, K) template
    indices (-1: none) and scores (N, K) where answers are templates of `Evaluation.templates`."""

    errors: np.ndarray
    same: np.ndarray
    seconds: float
    neighbours: np.ndarray | None = None
    scores: np.ndarray | None = None
    view_errors: np.ndarray | None = None
    separation: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (N,) see `neighbours.Ranking`
    angle_distance: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # pose angle, distance
    call_ms: np.ndarray | None = None


@dataclass
class Evaluation:
    config: Config
    samples: Samples
    templates: RenderedTemplates | None
    symmetries: Mapping[int, Symmetry]
    results: dict[str, MethodResult] = field(default_factory=dict)
    descriptors: dict[str, np.ndarray] = field(default_factory=dict)  # "templates" / "samples" (ours)
    seconds: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    extra: dict[str, object] = field(default_factory=dict)  # what the run was, for the JSON

    def summary(self, ks: Sequence[int] = range(1, K_MAX + 1)) -> dict:
        """The JSON report (the contract of issue 5, plus what the run was)."""
        c, s = self.config, self.samples

        def tables(m: np.ndarray) -> dict:
            out: dict = {name: accuracy(r.errors[m], r.same[m], ks) for name, r in self.results.items()}
            views = {n: r for n, r in self.results.items() if r.view_errors is not None}
            if views:
                out["view_direction"] = {
                    name: accuracy(r.view_errors[m], r.same[m], ks)  # type: ignore[index]
                    for name, r in views.items()
                }
            out["n_samples"] = int(m.sum())
            return out

        everything = tables(np.ones(len(s), bool))
        out: dict = {
            "modality": c.modality,
            "protocol": c.protocol,
            "error": "viewing direction"
            if c.protocol == "paper"
            else "3-D rotation, in-plane included (the viewing-direction error under view_direction)",
            "n_samples": len(s),
            "methods": {name: everything[name] for name in self.results},
            **({"view_direction": everything["view_direction"]} if "view_direction" in everything else {}),
            "per_object": {},
            "dataset": str(c.dataset),
            "scene": c.scene,
            "min_visib": c.min_visib,
            "test_data": s.source,
            "frames": sorted({int(f) for f in s.frame_ids}),
            "objects": sorted(self.symmetries),
            "unseen": list(c.unseen),
            "n_templates": len(self.templates) if self.templates is not None else 0,
            "model": str(c.model),
            **self.extra,
            "seconds": {k: round(v, 2) for k, v in self.seconds.items()},
            "notes": self.notes,
        }
        for obj in sorted({int(o) for o in s.obj_ids}):
            out["per_object"][str(obj)] = tables(s.obj_ids == obj)
        if c.unseen:
            for label, group in (("seen", False), ("unseen", True)):
                out[f"{label}_objects"] = tables(np.isin(s.obj_ids, c.unseen) == group)
        return out


def bar(total: int, desc: str, unit: str = "patch") -> tqdm:
    return tqdm(total=total, desc=desc, unit=unit, disable=None, leave=False)


def check_methods(methods: Sequence[str]) -> None:
    if unknown := set(methods) - set(METHODS):
        raise ValueError(f"unknown methods {sorted(unknown)}; use some of {', '.join(METHODS)}")


def evaluate(cfg: Config, embedder: Embedder | None = None) -> Evaluation:
    """Runs every method of `cfg.methods` on the same test patches and templates."""
    check_methods(cfg.methods)
    if cfg.protocol == "service":
        from evaluation.served import evaluate_served

        return evaluate_served(cfg)
    return _evaluate_templates(cfg, embedder or Embedder(cfg.model, threads=2))


def instances_of(cfg: Config, dataset: BopDataset, obj_ids: Sequence[int]):
    instances = select_instances(dataset, cfg.scene, cfg.min_visib, cfg.frames, obj_ids)
    if not instances:
        raise ValueError(
            f"{cfg.dataset}: no instance of scene {cfg.scene} with visible fraction ≥ {cfg.min_visib} "
            "in the frames and objects asked for"
        )
    return instances


def rank(name: str, cfg: Config, embedder: Embedder, ev: Evaluation, n: int) -> Ranking:
    """Method `name`'s n nearest templates of every test patch, with a progress bar."""
    t, s = ev.templates, ev.samples
    assert t is not None
    total = len(t) + (len(s) if name == "linemod" else 0)
    with bar(total, name, "item") as b:
        if name == "ours":
            return ours.rank(embedder, t, s, n, progress=b.update)
        if name == "hog":
            return hog.rank(embedder, t, s, n, progress=b.update)
        return linemod.rank(embedder, t, s, n, cfg.linemod_threshold, progress=b.update)


def _evaluate_templates(cfg: Config, embedder: Embedder) -> Evaluation:
    """The paper and full protocols: patches cut at the true centre and distance (and, for the paper's,
    rectified by the true in-plane angle), the 22 nearest templates of each method."""
    dataset = BopDataset(cfg.dataset)
    spec = embedder.info.spec
    obj_ids = list(cfg.objects) if cfg.objects else dataset.obj_ids
    seconds: dict[str, float] = {}
    notes: list[str] = []

    t0 = time.perf_counter()
    instances = instances_of(cfg, dataset, obj_ids)
    rectify = cfg.protocol == "paper"
    synthetic = needs_synthetic(cfg.modality, instances) if cfg.synthetic is None else cfg.synthetic
    with bar(len(instances), "test patches") as b:
        if synthetic:
            samples = synthetic_samples(
                dataset, instances, cfg.modality, spec, rectify, cfg.seed, progress=b.update
            )
            notes.append(SYNTHETIC_NOTE)
        else:
            samples = real_samples(instances, cfg.modality, spec, rectify, progress=b.update)
    seconds["test_patches"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    meshes = {o: dataset.mesh(o) for o in obj_ids}
    symmetries = {o: dataset.symmetry(o) for o in obj_ids}
    inplane = full_inplane(cfg.inplane_step or 20.0) if cfg.protocol == "full" else None
    views = {o: object_views(symmetries[o], inplane) for o in obj_ids}
    with bar(sum(map(len, views.values())), "render templates", "template") as b:
        templates = render_template_set(meshes, views, cfg.modality, spec.window_mm, progress=b.update)
    seconds["render_templates"] = time.perf_counter() - t0

    ev = Evaluation(cfg, samples, templates, symmetries, seconds=seconds, notes=notes)
    t_poses, s_poses = Poses.of(templates.views), Poses.of(samples.views)
    rng = np.random.default_rng(cfg.seed)
    hist_idx = rng.choice(len(samples), min(HISTOGRAM_SAMPLES, len(samples)), replace=False)
    for name in cfg.methods:
        t0 = time.perf_counter()
        r = rank(name, cfg, embedder, ev, K_MAX)
        ev.notes += r.notes
        if r.descriptors:
            ev.descriptors = r.descriptors
        errors = neighbour_errors(
            r.neighbours, templates.obj_ids, t_poses, samples.obj_ids, s_poses, symmetries, cfg.protocol
        )
        ev.results[name] = MethodResult(
            errors=errors,
            same=same_object(r.neighbours, templates.obj_ids, samples.obj_ids),
            seconds=time.perf_counter() - t0,
            neighbours=r.neighbours,
            scores=r.scores,
            separation=r.separation,
            angle_distance=_angle_distance(r, hist_idx, ev, t_poses, s_poses),
        )
        seconds[name] = ev.results[name].seconds
    return ev


def _angle_distance(r: Ranking, hist_idx, ev: Evaluation, t_poses: Poses, s_poses: Poses) -> np.ndarray:
    """(pose angle, distance) for every template of the patch's own object, for the patches `hist_idx`."""
    rows = []
    for i in hist_idx:
        obj = int(ev.samples.obj_ids[i])
        idx = ev.templates.of(obj)  # type: ignore[union-attr]
        angles = pose_errors(t_poses.take(idx), s_poses.take([i]), ev.symmetries[obj], ev.config.protocol)
        d = r.lookup(i, idx)
        ok = np.isfinite(d)
        rows.append(np.stack([angles[ok], d[ok]], axis=1))
    return np.concatenate(rows) if rows else np.zeros((0, 2))
