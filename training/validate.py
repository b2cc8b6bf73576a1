"""k = 1 nearest-neighbour accuracy during training: a test patch, rolled as the camera saw it, is matched
against the clean templates of all objects (their in-plane variants included); it counts at a threshold
when the object is right and the pose error is strictly below it. Two errors: the 3-D rotation angle
(in-plane included, `training.similarity.pose_distances`, symmetry-aware) and the angle between viewing
directions (`index.geometry.pose_error.view_error`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

from index.features.patches import batch_inputs
from index.geometry.pose import View
from index.geometry.pose_error import view_error
from index.geometry.sensor import SensorModel, random_background
from index.templates.render import Renderer
from index.templates.viewpoints import sphere_views
from training.data import TrainingData, test_input
from training.similarity import pose_distances, rotations

Embed = Callable[[np.ndarray], np.ndarray]  # network inputs (N, C, S, S) -> descriptors (N, D)
THRESHOLDS = (5.0, 20.0, 40.0)


@dataclass
class Accuracy:
    n: int
    recognised: float
    within: dict[float, float]  # threshold (deg) -> fraction right object and viewpoint error below it
    within_3d: dict[float, float]  # the same with the 3-D rotation error (in-plane included)

    def line(self) -> str:
        parts = " / ".join(f"{100 * self.within_3d[t]:.0f}" for t in THRESHOLDS)
        view = " / ".join(f"{100 * self.within[t]:.0f}" for t in THRESHOLDS)
        return f"3-D {parts}, view {view}, recognised {100 * self.recognised:.0f} % (5/20/40 deg, n={self.n})"

    def as_dict(self) -> dict:
        return {
            "n": self.n,
            "recognised": self.recognised,
            **{f"within_{t:g}": v for t, v in self.within.items()},
            **{f"within_3d_{t:g}": v for t, v in self.within_3d.items()},
        }


def nearest_neighbour(
    test_f: np.ndarray,
    test_obj: np.ndarray,
    test_views: Sequence[View],
    template_f: np.ndarray,
    template_obj: np.ndarray,
    template_views_: Sequence[View],
    symmetries: Sequence,
) -> Accuracy:
    """Scores each test descriptor by its nearest template. Shapes: (N, D), (N,), N; (M, D), (M,), M."""
    d2 = (test_f**2).sum(1)[:, None] - 2 * test_f @ template_f.T + (template_f**2).sum(1)[None]
    nn = np.argmin(d2, axis=1)
    right = template_obj[nn] == test_obj
    err = np.array(
        [
            view_error(
                template_views_[j].azimuth,
                template_views_[j].elevation,
                v.azimuth,
                v.elevation,
                symmetries[o],
            )
            for j, v, o in zip(nn, test_views, test_obj, strict=True)
        ]
    )
    err_3d = np.array(
        [
            pose_distances(rotations([template_views_[j]]), rotations([v]), symmetries[o])[0, 0]
            for j, v, o in zip(nn, test_views, test_obj, strict=True)
        ]
    )
    n = len(test_obj)
    return Accuracy(
        n,
        float(right.mean()) if n else 0.0,
        {t: float((right & (err < t)).mean()) if n else 0.0 for t in THRESHOLDS},
        {t: float((right & (err_3d < t)).mean()) if n else 0.0 for t in THRESHOLDS},
    )


def template_descriptors(
    data: TrainingData, embed: Embed, modality: str, objects: Sequence[int]
) -> np.ndarray:
    """Descriptors of the clean templates of `objects`, in-plane variants included. Shape: (len(objects) * T, D)."""
    inputs = data.template_inputs(modality)
    out = []
    for o in objects:
        for lo in range(0, data.n_templates, 1024):
            out.append(embed(inputs[o, lo : lo + 1024].astype(np.float32)))
    return np.concatenate(out)


def validate_real(
    data: TrainingData,
    embed: Embed,
    modality: str,
    seed: int = 0,
    split: str = "val",
    template_f: Callable[[int], np.ndarray] | None = None,
) -> tuple[Accuracy, dict]:
    """Real instances of the `split` frames (visibility >= min_visib_test), rolled as seen, against the
    templates of the BOP objects (`template_f(o)`: their descriptors, when the caller has them cheaper).
    Also returns accuracies by visibility band."""
    objects = list(range(data.real_objects))
    if template_f is None:
        tf = template_descriptors(data, embed, modality, objects)
    else:
        tf = np.concatenate([template_f(o) for o in objects])
    t_obj = np.repeat(objects, data.n_templates)
    t_views = data.template_views * len(objects)
    idx = data.test_instances(split)
    rng = np.random.default_rng(seed)
    x = np.stack([test_input(data, i, modality, rng) for i in idx]) if idx else np.zeros((0,))
    f = embed(x) if idx else np.zeros((0, tf.shape[1]), np.float32)
    obj = np.array([data.real[i].obj for i in idx], np.int64)
    views = [data.real[i].view for i in idx]  # azimuth and elevation are what the error uses
    acc = nearest_neighbour(f, obj, views, tf, t_obj, t_views, data.symmetries)
    bands = {}
    visib = np.array([data.real[i].visib for i in idx])
    for lo, hi in ((0.5, 0.8), (0.8, 0.95), (0.95, 1.01)):
        m = (visib >= lo) & (visib < hi)
        if m.any():
            bands[f"{lo:.2f}-{min(hi, 1):.2f}"] = nearest_neighbour(
                f[m],
                obj[m],
                [v for v, k in zip(views, m, strict=True) if k],
                tf,
                t_obj,
                t_views,
                data.symmetries,
            )
    return acc, bands


def validate_synthetic(
    objects: dict[str, tuple[trimesh.Trimesh, str]],
    embed: Embed,
    modality: str,
    views_per_object: int = 60,
    window_mm: float = 200.0,
    distance: float = 400.0,
    seed: int = 0,
    backgrounds: Sequence[np.ndarray] = (),
) -> Accuracy:
    """Renders clean templates of `objects` (name -> (mesh, symmetry)) and test views at random viewpoints
    of the upper hemisphere (off the template grid), through the sensor model over random backgrounds,
    and scores them against all the objects' templates. For objects the network never saw, and for
    depth, which the real data here lacks."""
    rng = np.random.default_rng(seed)
    renderer = Renderer(window_mm=window_mm)
    sensor = SensorModel()
    t_views = sphere_views(3, distance=distance)
    tf, t_obj, t_all, f, obj, test_views, syms = [], [], [], [], [], [], []
    try:
        for k, (mesh, sym) in enumerate(objects.values()):
            syms.append(sym)
            t = renderer.render(mesh, t_views)
            tf.append(embed(batch_inputs(modality, t.rgb, t.depth, distance, window_mm, fill=False)))
            t_obj += [k] * len(t_views)
            t_all += t_views
            z = rng.uniform(0.05, 1.0, views_per_object)  # uniform on the hemisphere
            az = rng.uniform(0, 360, views_per_object)
            views = [
                View(float(a), float(np.degrees(np.arcsin(e))), 0.0, distance)
                for a, e in zip(az, z, strict=True)
            ]
            r = renderer.render(mesh, views)
            rgb, depth = [], []
            for i in range(len(views)):
                bg = random_background(r.depth[i].shape, rng, distance, backgrounds)
                a, b = sensor.apply(r.rgb[i], r.depth[i], rng, *bg)
                rgb.append(a)
                depth.append(b)
            f.append(
                embed(batch_inputs(modality, np.stack(rgb), np.stack(depth), distance, window_mm, fill=True))
            )
            obj += [k] * len(views)
            test_views += views
    finally:
        renderer.close()
    return nearest_neighbour(
        np.concatenate(f), np.array(obj), test_views, np.concatenate(tf), np.array(t_obj), t_all, syms
    )
