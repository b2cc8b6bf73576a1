"""The paper's protocols (`posedesc evaluate --protocol paper` and `full`): test patches cut at the true
centre and distance (and, for `paper`, rectified by the true in-plane angle), ranked against one rendered
template set by each method, 22 nearest each.

- paper: upright templates, the viewing-direction error (the paper's Table 1);
- full: every template also at in-plane angles over the whole turn (`evaluation.paper.templates.full_inplane`,
  `Config.inplane_step` apart, default 20°), the 3-D rotation error."""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np

from evaluation.config import Config
from evaluation.paper.methods import rank
from evaluation.paper.metric import K_MAX, Poses, neighbour_errors, pose_errors, same_object
from evaluation.paper.neighbours import Ranking
from evaluation.paper.samples import (
    SYNTHETIC_NOTE,
    instances_of,
    needs_synthetic,
    real_samples,
    synthetic_samples,
)
from evaluation.paper.templates import RenderedTemplates, full_inplane, object_views, render_template_set
from evaluation.progress import bar
from evaluation.results import Evaluation, MethodResult
from index.data.bop import BopDataset
from index.features.embed import Embedder
from index.geometry.pose import View
from index.geometry.symmetry import Symmetry

#: Test patches per picture of descriptor distance against pose angle (all templates of their object).
HISTOGRAM_SAMPLES = 150
#: The full protocol's in-plane step by default, degrees (18 variants a viewpoint).
FULL_INPLANE_STEP = 20.0


def protocol_views(cfg: Config, symmetries: Mapping[int, Symmetry]) -> dict[int, list[View]]:
    """Each object's template views under `cfg.protocol` (upright for paper, turned for full)."""
    inplane = full_inplane(cfg.inplane_step or FULL_INPLANE_STEP) if cfg.protocol == "full" else None
    return {o: object_views(symmetries[o], inplane) for o in symmetries}


def evaluate_templates(
    cfg: Config, embedder: Embedder, templates: RenderedTemplates | None = None
) -> Evaluation:
    """Every method of `cfg.methods` on the same test patches and templates. `templates`: rendered
    already (`render_template_set` of `protocol_views`, for these objects; a set rendered for "rgbd"
    serves every modality); None: rendered here."""
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

    symmetries = {o: dataset.symmetry(o) for o in obj_ids}
    if templates is None:
        t0 = time.perf_counter()
        meshes = {o: dataset.mesh(o) for o in obj_ids}
        views = protocol_views(cfg, symmetries)
        with bar(sum(map(len, views.values())), "render templates", "template") as b:
            templates = render_template_set(meshes, views, cfg.modality, spec.window_mm, progress=b.update)
        seconds["render_templates"] = time.perf_counter() - t0
    elif set(np.unique(templates.obj_ids).tolist()) != set(obj_ids):
        raise ValueError(
            f"the templates given are of objects {sorted(set(templates.obj_ids))}, not {obj_ids}"
        )

    ev = Evaluation(cfg, samples, templates, symmetries, seconds=seconds, notes=notes)
    t_poses, s_poses = Poses.of(templates.views), Poses.of(samples.views)
    rng = np.random.default_rng(cfg.seed)
    hist_idx = rng.choice(len(samples), min(HISTOGRAM_SAMPLES, len(samples)), replace=False)
    for name in cfg.methods:
        t0 = time.perf_counter()
        r = rank(name, embedder, templates, samples, K_MAX, cfg.linemod_threshold)
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
