"""The service protocol scored the BOP way: each target instance's errors of the service's best answer
(MSSD, MSPD, ADD(-S), te, re, "5°, 5 cm", `index.geometry.pose_error`) and the pooled block (AR_MSSD, AR_MSPD, AR,
`evaluation.bop.recall`; recall of ADD(-S) < 0.1 d and of "5°, 5 cm") that `posedesc evaluate` writes
under "bop", and the best answers as BOP19 results rows (`evaluation.bop.csv`). The detect protocol's block
(`detections_block`) has the same figures from several scored estimates a frame, matched as BOP matches them.

An instance whose best answer is missing (rejected: "no known object", refused, or none) or names another
object has no estimate of its object: every error is missing (null in the JSON) and counts as infinitely
wrong, as BOP counts a target without a matching estimate."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

from evaluation.bop.csv import Estimate
from evaluation.bop.recall import (
    MSPD_REFERENCE_WIDTH,
    MSPD_THRESHOLDS,
    MSSD_THRESHOLDS,
    VSD_TAUS,
    VSD_THRESHOLDS,
    BopRecall,
    bop_matches,
    bop_recall,
)
from evaluation.bop.vsd import NO_VSD_NOTE, VSD_NOTE, Vsd
from index.data.bop import Instance
from index.geometry.pose_error import (
    ADD_FRACTION,
    DEG_CM,
    add,
    add_s_correct,
    adi,
    missing_as_inf,
    mspd,
    mssd,
    re,
    te,
    within_deg_cm,
)
from index.geometry.symmetry import transformations_from_bop

#: The model's points are its mesh vertices, at most this many (a fixed-seed sample): MSSD, MSPD and ADD are
#: maxima or means over points, and 1,000 of LM-O's ~5,000-20,000 vertices keep a run's scoring to seconds.
MAX_POINTS = 1000
POINTS_SEED = 0
#: The score of an answer without a confidence (its model has no calibration of the score kind).
NO_CONFIDENCE_SCORE = 1.0
#: BOP19's own targets: instances at least this visible (ours are those the protocol sends).
BOP_MIN_VISIB = 0.1
ERRORS = ("mssd", "mspd", "add_s", "te", "re")
#: How both protocols' "bop" blocks measure, said in the JSON.
CONVENTIONS = {
    "model_points": f"mesh vertices, at most {MAX_POINTS} (a sample, seed {POINTS_SEED})",
    "symmetries": "BOP's models_info.json (index.geometry.symmetry.transformations_from_bop); ADD-S for objects "
    "with symmetries, ADD for the others",
    "criteria": f"ADD(-S) < {ADD_FRACTION} d; '5 deg, 5 cm': re < {DEG_CM[0]} deg and te < {DEG_CM[1]} "
    "mm under one symmetric pose; re as BOP defines it (no symmetry forgiven)",
}


@dataclass(frozen=True)
class ObjectModel:
    """What BOP's errors need of one object: points (N, 3) mm, diameter mm, symmetry transformations
    (identity first; `index.geometry.symmetry.transformations_from_bop`)."""

    pts: np.ndarray
    diameter: float
    syms: list[tuple[np.ndarray, np.ndarray]]

    @property
    def symmetric(self) -> bool:
        return len(self.syms) > 1


def model_points(mesh: trimesh.Trimesh, most: int = MAX_POINTS, seed: int = POINTS_SEED) -> np.ndarray:
    """The mesh's vertices (N, 3), at most `most` of them (a sample without replacement, fixed seed)."""
    v = np.asarray(mesh.vertices, float)
    if len(v) <= most:
        return v
    return v[np.sort(np.random.default_rng(seed).choice(len(v), most, replace=False))]


def object_model(info: dict, mesh: trimesh.Trimesh) -> ObjectModel:
    """An object from its `models_info.json` entry (diameter, BOP's symmetries) and its full mesh."""
    return ObjectModel(model_points(mesh), float(info["diameter"]), transformations_from_bop(info))


@dataclass(frozen=True)
class Best:
    """The service's best answer to one query: the dataset's object id, R (3, 3), t (3,) mm, confidence
    (None: uncalibrated), the query's seconds."""

    obj_id: int
    R: np.ndarray
    t: np.ndarray
    confidence: float | None
    seconds: float


def instance_errors(
    inst: Instance, best: Best | Estimate | None, model: ObjectModel, vsd: Vsd | None = None
) -> dict[str, float | bool | list[float] | None]:
    """The BOP errors of `best` against `inst`'s ground truth: mssd (mm), mspd (px), add_s (ADD for an
    object without symmetries, ADD-S with), te (mm), re (degrees, BOP's: no symmetry forgiven), deg_cm
    ("5°, 5 cm" under the object's symmetries), with `vsd` the VSD at each of `VSD_TAUS`; None (and
    deg_cm False) where there is no estimate of the instance's object."""
    if best is None or best.obj_id != inst.obj_id:
        return {**dict.fromkeys(ERRORS), "deg_cm": False, **({"vsd": None} if vsd is not None else {})}
    R, t, pts = best.R, best.t, model.pts
    return {
        **({"vsd": vsd.errors(inst, R, t)} if vsd is not None else {}),
        "mssd": mssd(R, t, inst.R, inst.t, pts, model.syms),
        "mspd": mspd(R, t, inst.R, inst.t, inst.K, pts, model.syms),
        "add_s": (adi if model.symmetric else add)(R, t, inst.R, inst.t, pts),
        "te": te(t, inst.t),
        "re": re(R, inst.R),
        "deg_cm": bool(within_deg_cm(R, t, inst.R, inst.t, model.syms)),
    }


def _missing(values: Sequence[float | None]) -> np.ndarray:
    return missing_as_inf([np.nan if v is None else v for v in values])


def pooled(per_instance: Sequence[dict], image_width: float) -> dict:
    """The pooled figures over the targets `per_instance` (each with its errors, "diameter" and
    "deg_cm", and "vsd" where it was measured): AR_MSSD, AR_MSPD, AR_VSD where every target has its
    "vsd" (None: no estimate), AR (the mean of those there are), their recall per threshold, and the recall
    of ADD(-S) < 0.1 d and of "5°, 5 cm"."""
    if not per_instance:
        raise ValueError("no targets to score")
    d = np.array([p["diameter"] for p in per_instance], float)
    vsd = None
    if all("vsd" in p for p in per_instance):
        vsd = np.array([[np.inf] * len(VSD_TAUS) if p["vsd"] is None else p["vsd"] for p in per_instance])
    r = bop_recall(
        _missing([p["mssd"] for p in per_instance]),
        _missing([p["mspd"] for p in per_instance]),
        d,
        image_width,
        vsd,
    )
    return figures(
        r,
        float(add_s_correct(_missing([p["add_s"] for p in per_instance]), d).mean()),
        float(np.mean([p["deg_cm"] for p in per_instance])),
        len(per_instance),
        int(sum(p["mssd"] is not None for p in per_instance)),
    )


def figures(
    r: BopRecall, recall_add_s: float, recall_deg_cm: float, n_targets: int, n_estimated: int
) -> dict:
    """The figures of a "bop" block, the service and detect protocols alike."""
    return {
        "ar": r.ar,
        "ar_mssd": r.ar_mssd,
        "ar_mspd": r.ar_mspd,
        "ar_vsd": r.ar_vsd,
        "recall_mssd": dict(zip((f"{x:g}d" for x in MSSD_THRESHOLDS), map(float, r.mssd), strict=True)),
        "recall_mspd": dict(zip((f"{x:g}px" for x in MSPD_THRESHOLDS), map(float, r.mspd), strict=True)),
        "recall_add_s": recall_add_s,
        "recall_5deg_5cm": recall_deg_cm,
        "n_targets": n_targets,
        "n_estimated": n_estimated,
    }


def bop_block(
    instances: Sequence[Instance],
    bests: Sequence[Best | None],
    models: dict[int, ObjectModel],
    image_width: float,
    min_visib: float,
    vsd: Vsd | None = None,
) -> dict:
    """The "bop" block of the JSON: the pooled figures, what they were measured on, and per instance its
    errors (in the order sent); with `vsd` (frames with recorded depth) VSD too."""
    per_instance = [
        {
            "scene_id": inst.scene_id,
            "im_id": inst.frame_id,
            "obj_id": inst.obj_id,
            "visib": round(float(inst.visib_fract), 3),
            "answer_obj_id": None if best is None else best.obj_id,
            "diameter": models[inst.obj_id].diameter,
            "add_kind": "ADD-S" if models[inst.obj_id].symmetric else "ADD",
            **instance_errors(inst, best, models[inst.obj_id], vsd),
        }
        for inst, best in zip(instances, bests, strict=True)
    ]
    return {
        **pooled(per_instance, image_width),
        "image_width": image_width,
        "targets": (
            f"the instances the protocol sends (visible fraction >= {min_visib}), one estimate each: the "
            f"service's best answer (k = 1); BOP19's own targets are those with visib >= {BOP_MIN_VISIB}"
        ),
        "missing": "no estimate of the instance's object (rejected, refused, or another object named): "
        "errors null, wrong at every threshold, as BOP counts a target without a matching estimate",
        **CONVENTIONS,
        "vsd": NO_VSD_NOTE if vsd is None else VSD_NOTE,
        "estimates": "--bop-csv rows: the best answer of each query not rejected, obj_id the object it "
        f"names, score its confidence ({NO_CONFIDENCE_SCORE} where the model has no calibration to give one), "
        "time the seconds of that query's recognise call (BOP's is the whole image's)",
        "per_instance": per_instance,
    }


def estimates(instances: Sequence[Instance], bests: Sequence[Best | None]) -> list[Estimate]:
    """The BOP19 results rows: each query's best answer (k = 1) with the object it names; a rejected or
    refused query writes none (a method that reports nothing); score = the confidence, or
    `NO_CONFIDENCE_SCORE` without one; time = the query's seconds."""
    return [
        Estimate(
            inst.scene_id,
            inst.frame_id,
            best.obj_id,
            NO_CONFIDENCE_SCORE if best.confidence is None else best.confidence,
            best.R,
            best.t,
            best.seconds,
        )
        for inst, best in zip(instances, bests, strict=True)
        if best is not None
    ]


def detections_block(
    instances: Sequence[Instance],
    ests: Sequence[Estimate],
    models: Mapping[int, ObjectModel],
    image_width: float,
    vsd: Vsd | None = None,
) -> dict:
    """The detect protocol's "bop" block: several scored estimates an image, matched to the targets as BOP
    matches them. Targets: the `instances` at least `BOP_MIN_VISIB` visible. Per image and object only
    its n best-scored estimates count (n: its targets there), and at each threshold they take targets
    greedily by score (`evaluation.bop.recall.bop_matches`); an estimate of an object with no target in
    its image costs nothing, as in BOP. The figures pooled over all targets and per object; each target's
    errors are those of its nearest (by MSSD) counted estimate, the one BOP matches when the image holds
    one instance of the object (every LM-O image). With `vsd` (frames with recorded depth), VSD too: matched
    at each tau and threshold as the other errors are at theirs."""
    targets = [i for i in instances if i.visib_fract >= BOP_MIN_VISIB]
    if not targets:
        raise ValueError("no targets to score")
    groups: dict[tuple[int, int, int], list[int]] = {}
    for j, inst in enumerate(targets):
        groups.setdefault((inst.scene_id, inst.frame_id, inst.obj_id), []).append(j)
    of_key: dict[tuple[int, int, int], list[Estimate]] = {}
    for e in ests:
        of_key.setdefault((e.scene_id, e.im_id, e.obj_id), []).append(e)
    px = MSPD_THRESHOLDS * image_width / MSPD_REFERENCE_WIDTH
    found = {
        k: np.zeros((len(targets), n), bool) for k, n in (("mssd", len(MSSD_THRESHOLDS)), ("mspd", len(px)))
    }
    found |= {k: np.zeros((len(targets), 1), bool) for k in ("add_s", "deg_cm")}
    found_vsd = np.zeros((len(targets), len(VSD_TAUS), len(VSD_THRESHOLDS)), bool)
    per_instance: list[dict] = [{} for _ in targets]
    for key, js in groups.items():
        model = models[key[2]]
        top = sorted(of_key.get(key, []), key=lambda e: -e.score)[: len(js)]
        errors = [[instance_errors(targets[j], e, model, vsd) for j in js] for e in top]

        def grid(name: str, errors: list = errors, n: int = len(js)) -> np.ndarray:
            # deg_cm is a verdict: 0 where right, so that it matches below any positive threshold
            g = [
                [(0.0 if r["deg_cm"] else np.inf) if name == "deg_cm" else r[name] for r in row]
                for row in errors
            ]
            return np.array(g, float).reshape(len(errors), n)

        thresholds = {
            "mssd": model.diameter * MSSD_THRESHOLDS,
            "mspd": px,
            "add_s": [ADD_FRACTION * model.diameter],
            "deg_cm": [1.0],
        }
        scores = [e.score for e in top]
        for name, th in thresholds.items():
            found[name][js] = bop_matches(scores, grid(name), np.asarray(th, float)).T
        if vsd is not None:
            v = np.array([[r["vsd"] or [np.inf] * len(VSD_TAUS) for r in row] for row in errors], float)
            v = v.reshape(len(errors), len(js), len(VSD_TAUS))
            for k in range(len(VSD_TAUS)):
                found_vsd[js, k] = bop_matches(scores, v[:, :, k], VSD_THRESHOLDS).T
        mssd_grid = grid("mssd")
        for g, j in enumerate(js):
            inst = targets[j]
            near = int(np.argmin(mssd_grid[:, g])) if top else None
            per_instance[j] = {
                "scene_id": inst.scene_id,
                "im_id": inst.frame_id,
                "obj_id": inst.obj_id,
                "visib": round(float(inst.visib_fract), 3),
                "diameter": model.diameter,
                "add_kind": "ADD-S" if model.symmetric else "ADD",
                "n_estimates": len(top),
                "score": None if near is None else top[near].score,
                **(instance_errors(inst, None, model, vsd) if near is None else errors[near][g]),
            }

    def block(rows: list[int]) -> dict:
        r = BopRecall(
            found["mssd"][rows].mean(0),
            found["mspd"][rows].mean(0),
            None if vsd is None else found_vsd[rows].mean(0),
        )
        return figures(
            r,
            float(found["add_s"][rows].mean()),
            float(found["deg_cm"][rows].mean()),
            len(rows),
            sum(per_instance[j]["n_estimates"] > 0 for j in rows),
        )

    objects = sorted({t.obj_id for t in targets})
    return {
        **block(list(range(len(targets)))),
        "image_width": image_width,
        "targets": f"every instance at least {BOP_MIN_VISIB} visible (BOP19's rule; the detection figures' "
        "targets are those at least half visible)",
        "matching": "per image and object, its n best-scored estimates (n: its targets there), greedy by "
        "score at each threshold (bop_toolkit's matching); a target no estimate matches is wrong",
        **CONVENTIONS,
        "vsd": NO_VSD_NOTE if vsd is None else VSD_NOTE,
        "per_object": {str(o): block([j for j, t in enumerate(targets) if t.obj_id == o]) for o in objects},
        "per_instance": per_instance,
    }
