"""The report's pictures (matplotlib, Agg): accuracy against threshold, descriptor distance against pose
angle, class separation, test patches beside their nearest templates, descriptors in 3-D."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from evaluation.results import Evaluation  # noqa: E402
from index.geometry.pose_error import within  # noqa: E402
from index.templates.sheet import depth_to_colour  # noqa: E402

COLOURS = {"ours": "tab:blue", "hog": "tab:orange", "linemod": "tab:green"}
LABELS = {"ours": "ours", "hog": "HOG", "linemod": "LineMOD"}


def _title(ev: Evaluation) -> str:
    c = ev.config
    return f"{c.modality}, {c.protocol} protocol, {ev.samples.source} data, {len(ev.samples)} patches"


def accuracy_curves(ev: Evaluation, path: Path, ks: tuple[int, ...] = (1, 5, 22)) -> Path:
    """Fraction of patches within each threshold (strictly below; best of k nearest; wrong object never
    counts)."""
    thresholds = np.linspace(0, 180, 181)
    fig, axes = plt.subplots(1, len(ks), figsize=(4.2 * len(ks), 3.6), sharey=True)
    for ax, k in zip(np.atleast_1d(axes), ks, strict=True):
        for name, r in ev.results.items():
            best = np.where(r.same[:, :k], r.errors[:, :k], np.inf).min(axis=1)
            curve = [np.mean(within(best, t)) for t in thresholds]
            ax.plot(thresholds, curve, color=COLOURS[name], label=LABELS[name])
        for t in (5, 20, 40):
            ax.axvline(t, color="0.85", lw=0.8, zorder=0)
        ax.set(title=f"k = {k}", xlabel="pose error threshold (deg)", xlim=(0, 180), ylim=(0, 1))
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].set_ylabel("fraction of test patches")
    np.atleast_1d(axes)[0].legend(loc="lower right")
    fig.suptitle(_title(ev))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def distance_vs_angle(ev: Evaluation, path: Path) -> Path:
    """2-D histograms: pose angle between a test patch and each template of its object, against the
    method's distance (LineMOD: 100 - similarity, matched templates only)."""
    names = list(ev.results)
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.6))
    for ax, name in zip(np.atleast_1d(axes), names, strict=True):
        pairs = ev.results[name].angle_distance
        if len(pairs):
            ax.hist2d(pairs[:, 0], pairs[:, 1], bins=(36, 40), cmap="magma", norm=matplotlib.colors.LogNorm())
        ylabel = "100 - similarity" if name == "linemod" else "descriptor distance"
        ax.set(title=LABELS[name], xlabel="pose angle (deg)", ylabel=ylabel)
    fig.suptitle("distance vs pose angle, same object: " + _title(ev))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def class_separation(ev: Evaluation, path: Path) -> Path:
    """Histogram of nearest-other-object distance / nearest-same-object distance (> 1 is separated)."""
    fig, ax = plt.subplots(figsize=(6, 3.6))
    ratios = {
        name: r.separation[np.isfinite(r.separation) & (r.separation > 0)] for name, r in ev.results.items()
    }
    span = max([np.abs(np.log10(x)).max() for x in ratios.values() if len(x)] + [0.05])
    bins = np.linspace(-min(span, 1.0), min(span, 1.0), 61)
    for name, ratio in ratios.items():
        if len(ratio):
            frac = np.mean(ratio > 1)
            ax.hist(
                np.clip(np.log10(ratio), -1, 1), bins=bins, histtype="step", lw=1.6,  # type: ignore[arg-type]
                color=COLOURS[name], label=f"{LABELS[name]} ({100 * frac:.0f}% > 1)",
            )  # fmt: skip
    ax.axvline(0, color="k", lw=0.8)
    ax.set(xlabel="log10(nearest other object / nearest same object)", ylabel="test patches")
    ax.legend()
    ax.set_title(_title(ev), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _show(rgb: np.ndarray | None, depth: np.ndarray | None, i: int) -> np.ndarray:
    return rgb[i] if rgb is not None else depth_to_colour(depth[i])  # type: ignore[index]


def nearest_templates(ev: Evaluation, method: str, path: Path, n: int = 8, k: int = 10) -> Path:
    """Rows of a test patch and its k nearest templates; frame: green = right object within 20°,
    orange = right object, red = another object."""
    s, t, r = ev.samples, ev.templates, ev.results[method]
    assert t is not None and r.neighbours is not None
    rng = np.random.default_rng(ev.config.seed)
    rows = np.sort(rng.choice(len(s), min(n, len(s)), replace=False))
    fig, axes = plt.subplots(len(rows), k + 1, figsize=(1.1 * (k + 1), 1.2 * len(rows)), squeeze=False)
    for a, i in zip(axes, rows, strict=True):
        a[0].imshow(_show(s.rgb, s.depth, i))
        a[0].set_title(f"obj {s.obj_ids[i]}", fontsize=7)
        for j in range(k):
            ax = a[j + 1]
            ti = r.neighbours[i, j] if j < r.neighbours.shape[1] else -1
            if ti >= 0:
                ax.imshow(_show(t.rgb, t.depth, ti))
                colour = "green" if within(r.errors[i, j], 20) else "orange" if r.same[i, j] else "red"
                for spine in ax.spines.values():
                    spine.set(color=colour, lw=2.5)
                ax.set_title(f"{r.errors[i, j]:.0f}°", fontsize=6, color=colour)
        for ax in a:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle(f"{LABELS[method]}: test patch, then its {k} nearest templates", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def descriptors_3d(points: np.ndarray, obj_ids: np.ndarray, title: str, path: Path) -> Path:
    """3-D scatter of template descriptors, one colour per object."""
    fig = plt.figure(figsize=(6, 5.5))
    ax = fig.add_subplot(projection="3d")
    for j, obj in enumerate(np.unique(obj_ids)):
        m = obj_ids == obj
        ax.scatter(*points[m].T, s=4, color=plt.cm.tab10(j % 10), label=f"obj {obj}", depthshade=False)
    ax.legend(fontsize=7, markerscale=3)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def pca3(x: np.ndarray) -> np.ndarray:
    """The first three principal components of rows of x. Shape: (N, 3)."""
    x = x - x.mean(axis=0)
    _, _, vt = np.linalg.svd(x, full_matrices=False)
    return x @ vt[:3].T
