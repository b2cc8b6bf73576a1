"""The three methods by name, each ranking the same templates for the same test patches: ours
(`evaluation.paper.ours`), HOG (`evaluation.baselines.hog`) and LineMOD (`evaluation.baselines.linemod`)."""

from __future__ import annotations

from evaluation.baselines import hog, linemod
from evaluation.paper import ours
from evaluation.paper.neighbours import Ranking
from evaluation.paper.samples import Samples
from evaluation.paper.templates import RenderedTemplates
from evaluation.progress import bar
from index.features.embed import Embedder


def rank(
    name: str,
    embedder: Embedder,
    templates: RenderedTemplates,
    samples: Samples,
    n: int,
    linemod_threshold: float,
) -> Ranking:
    """Method `name`'s n nearest templates of every test patch, with a progress bar."""
    total = len(templates) + (len(samples) if name == "linemod" else 0)
    with bar(total, name, "item") as b:
        if name == "ours":
            return ours.rank(embedder, templates, samples, n, progress=b.update)
        if name == "hog":
            return hog.rank(embedder, templates, samples, n, progress=b.update)
        return linemod.rank(embedder, templates, samples, n, linemod_threshold, progress=b.update)
