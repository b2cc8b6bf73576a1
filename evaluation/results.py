"""What one evaluation found: each method's answers scored (`MethodResult`), and everything the JSON,
the report and the pictures need (`Evaluation`, whose `summary` is the JSON contract)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from evaluation.bop.csv import Estimate
from evaluation.config import Config
from evaluation.paper.metric import K_MAX, WRONG_OBJECT, accuracy
from evaluation.paper.samples import Samples
from evaluation.paper.templates import RenderedTemplates
from index.geometry.symmetry import Symmetry


@dataclass
class MethodResult:
    """One method's answers. errors (N, K) degrees, wrong object 180: the viewing-direction error (paper)
    or the 3-D rotation error (full, service); same (N, K): the right object; the service protocol adds
    view_errors (N, K) and, for ours, each recognise call's milliseconds. neighbours (N, K) template
    indices (-1: none) and scores (N, K) where answers are templates of `Evaluation.templates`.

    The service protocol's ours counts what `POST /recognize` answers with the open set on (`open_set`):
    `rejected` (N,) the queries answered "no known object", `open_set_off` the same answers scored as
    ranked, as if nothing were rejected."""

    errors: np.ndarray
    same: np.ndarray
    seconds: float
    neighbours: np.ndarray | None = None
    scores: np.ndarray | None = None
    view_errors: np.ndarray | None = None
    separation: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (N,) see `neighbours.Ranking`
    angle_distance: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # pose angle, distance
    call_ms: np.ndarray | None = None
    rejected: np.ndarray | None = None
    open_set_off: MethodResult | None = None


def open_set(r: MethodResult, rejected: np.ndarray) -> MethodResult:
    """`r` as a user of the service gets it: a query the service rejected (`rejected` (N,) bool: best is
    null, `service.rejection`) is a miss at every k, whatever it ranked (its other answers are farther
    than the rejected nearest one, so none of them stands either); `r` is kept as `open_set_off`."""
    miss = np.asarray(rejected, bool)[:, None]
    return replace(
        r,
        errors=np.where(miss, WRONG_OBJECT, r.errors),
        same=r.same & ~miss,
        view_errors=None if r.view_errors is None else np.where(miss, WRONG_OBJECT, r.view_errors),
        rejected=np.asarray(rejected, bool),
        open_set_off=r,
    )


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
    #: the service protocol's best answers as BOP19 results rows (`evaluation.bop.scores.estimates`)
    bop_estimates: list[Estimate] = field(default_factory=list)

    def summary(self, ks: Sequence[int] = range(1, K_MAX + 1)) -> dict:
        """The JSON report (the contract of issue 5, plus what the run was). With the open set (the
        service protocol), "methods" and "view_direction" count rejected answers as misses;
        "open_set_off" holds the same tables as ranked, "rejected" how many were."""
        c, s = self.config, self.samples

        def tables(m: np.ndarray) -> dict:
            out: dict = {name: accuracy(r.errors[m], r.same[m], ks) for name, r in self.results.items()}
            if views := _view_tables(self.results, m, ks):
                out["view_direction"] = views
            off = {n: r.open_set_off for n, r in self.results.items() if r.open_set_off is not None}
            if off:
                out["open_set_off"] = {
                    "methods": {n: accuracy(r.errors[m], r.same[m], ks) for n, r in off.items()},
                    **({"view_direction": v} if (v := _view_tables(off, m, ks)) else {}),
                }
                out["rejected"] = {
                    n: _rejected(self.results[n].rejected[m], r.same[m])  # type: ignore[index]
                    for n, r in off.items()
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
            **{k: everything[k] for k in ("view_direction", "open_set_off", "rejected") if k in everything},
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


def _view_tables(results: Mapping[str, MethodResult], m: np.ndarray, ks: Sequence[int]) -> dict:
    return {
        name: accuracy(r.view_errors[m], r.same[m], ks)
        for name, r in results.items()
        if r.view_errors is not None
    }


def _rejected(rejected: np.ndarray, same: np.ndarray) -> dict[str, float | int]:
    """How many queries were rejected, their share, and how many of them ranked the right object first."""
    return {
        "n": int(rejected.sum()),
        "share": float(rejected.mean()) if len(rejected) else 0.0,
        "right_object_first": int((rejected & same[:, 0]).sum()),
    }
