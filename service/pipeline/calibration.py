"""Whether a model's rejection calibration (`service.rejection.Calibration`) was made by the pipeline that
serves it: the settings and stage constants a score's answers depend on (`settings_of`, recorded with each
calibration by `scripts/calibrate_reject.py`), and the models whose calibration was made otherwise
(`stale`: logged at start-up, listed by `GET /readyz`)."""

from __future__ import annotations

from collections.abc import Mapping

from index.features.embed import Embedder
from index.templates.register import TemplateConfig
from service.pipeline import refine
from service.pipeline import score as scoring
from service.rejection import read_calibrations, served_score
from service.settings import Settings


def settings_of(settings: Settings, embedder: Embedder, score: str) -> dict[str, object]:
    """The settings a `score` kind's answers of this model depend on (`Calibration.settings`): the
    templates (level, in-plane step and extent, as `index.templates.register.TemplateConfig` makes them for the
    model), the query's turns, and with "local" the re-ranking's settings and the refinement's constants
    (`service.pipeline.refine`); the mask's weight (`service.pipeline.score.MASK_COVERAGE`) and the relief's
    only where the model has a mask and depth."""
    cfg = TemplateConfig(settings.level, settings.inplane_step, settings.inplane_max)
    step = embedder.info.inplane_step
    angles = [float(a) for a in cfg.inplane(step)]
    out: dict[str, object] = {
        "level": settings.level,
        "inplane_step": cfg.inplane_spacing(step),
        "inplane_extent": max(abs(a) for a in angles) if len(angles) > 1 else 0.0,
        "query_turns": settings.query_turns,
    }
    if score == "local":
        out |= {
            "rerank": settings.rerank,
            "roll_sweep": settings.roll_sweep,
            "roll_refine": refine.ROLL_REFINE,
            "refine_rounds": refine.REFINE_ROUNDS,
        }
        if embedder.has_mask:
            out["mask_coverage"] = scoring.MASK_COVERAGE
        if embedder.modality != "rgb":
            out["relief_weight"] = settings.relief_weight
    return out


def stale(settings: Settings, embedders: Mapping[str, Embedder]) -> dict[str, str]:
    """Modality -> how the model's calibration of the score it is served with was made with other settings
    than `settings` (its threshold and confidences were measured on other scores); models whose
    calibration matches, or that have none, are not listed."""
    out = {}
    for modality, e in sorted(embedders.items()):
        score = served_score(settings, e)
        cal = read_calibrations(e.info.extra, e.path.name).get(score)
        if cal is None:
            continue
        if cal.settings is None:
            out[modality] = f"{e.path.name}: its {score} calibration does not say which settings made it"
            continue
        if cal.graph is not None and cal.graph != e.graph_digest:
            out[modality] = (
                f"{e.path.name}: its {score} calibration was measured on another network (graph "
                f"{cal.graph}, this file's {e.graph_digest}): recalibrate (scripts/calibrate_reject.py)"
            )
            continue
        running = settings_of(settings, e, score)
        differ = [
            f"{k} {cal.settings.get(k)} (calibrated) != {v} (running)"
            for k, v in running.items()
            if cal.settings.get(k) != v
        ]
        if differ:
            out[modality] = (
                f"{e.path.name}: its {score} calibration was made with other settings: " + ", ".join(differ)
            )
    return out
