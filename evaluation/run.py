"""One evaluation, by protocol: `--protocol service` (`evaluation.served`) is what a user of
`POST /recognize` gets; `paper` and `full` (`evaluation.paper.protocol`) cut the test patches at the true centre
and distance themselves and retrieve the 22 nearest templates with each method (adapters:
`evaluation.paper.ours`, `hog`, `linemod`). Everything the report and the pictures need is kept on the returned
`evaluation.results.Evaluation`."""

from __future__ import annotations

from evaluation.config import Config, check_methods
from evaluation.paper.protocol import evaluate_templates
from evaluation.results import Evaluation
from evaluation.served import evaluate_served
from index.features.embed import Embedder


def evaluate(cfg: Config, embedder: Embedder | None = None) -> Evaluation:
    """Runs every method of `cfg.methods` on the same test patches and templates. `embedder`: the model
    for the paper's protocols (the service protocol loads its own, as the service does)."""
    check_methods(cfg.methods)
    if cfg.protocol == "service":
        return evaluate_served(cfg)
    return evaluate_templates(cfg, embedder or Embedder(cfg.model, threads=2))
