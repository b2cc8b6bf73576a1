"""Open-set answers through the service protocol: which objects `recognise` answers, and at what scores,
when only some of the dataset's objects are registered.

Every object is registered once by the service's own registration (`evaluation.served`), into a real store
in a temporary folder; each registered set of a run is a copy of that store with the other objects removed
by the store's own removal (what `DELETE /objects/{id}` does), so "not registered" is exactly what a user
who never registered the object gets: the re-ranking's candidates, its roll sweep and its refinement all
run without the object, which filtering one collection's answers afterwards would not reproduce (measured:
`scripts/calibrate_reject.py --compare-filtered`). Every instance of the frames is then sent to `recognise`
as a user sends it (`evaluation.queries.query`) with the service's settings, with re-ranking on (the
local-feature distance, when the model has local features) and off (the descriptor distance). A dataset
without depth (LM-O) is sent with its real colour and depth rendered from the ground truth, as `posedesc
evaluate --protocol service` sends it (`evaluation.paper.samples.served_data`)."""

from __future__ import annotations

import json
import shutil
import tempfile
from collections.abc import Sequence
from contextlib import closing, nullcontext
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from evaluation.calibration import at_least, auc, fit_logistic, keep_threshold, rejection_curve
from evaluation.paper.samples import RENDERED, select_instances, served_data
from evaluation.progress import bar
from evaluation.queries import frame_files, query
from evaluation.served import register_objects
from index.data.bop import BopDataset
from index.features.embed import Embedder
from index.store import Match
from index.templates.render import Renderer
from service.errors import ApiError
from service.pipeline.calibration import settings_of
from service.recognition import recognise
from service.rejection import LISTED as REJECT_LISTED
from service.rejection import MEASURES, Calibration, Term
from service.settings import Settings
from service.state import AppState, close_state, load_state

#: answers kept per query: the scores that look past the best answer (`service.rejection`) read the
#: best answer of another object among them
LISTED = 40


@dataclass
class Answers:
    """One row per (registered set, instance): obj (its object), registered (its object was), run (index of
    the registered set), frame and scene; per score kind ("local", "descriptor") the answers' dataset object ids
    (n, LISTED), -1 past the last (a refused query has none) and their distances (n, LISTED), nan past the
    last. `settings`: what the answers were made with (`service.pipeline.calibration.settings_of`); `data`: what
    the frames were (`evaluation.paper.samples.served_data`)."""

    obj: list[int] = field(default_factory=list)
    registered: list[bool] = field(default_factory=list)
    run: list[int] = field(default_factory=list)
    frame: list[int] = field(default_factory=list)
    scene: list[int] = field(default_factory=list)  # empty in answers collected before scenes were kept
    objects: dict[str, list[list[int]]] = field(default_factory=dict)
    distances: dict[str, list[list[float]]] = field(default_factory=dict)
    settings: dict[str, dict[str, object]] = field(default_factory=dict)
    data: str = ""
    #: per score kind, the best answer's colour distance (`Result.colour_distance`; None: not measured, or
    #: answers collected before it was kept)
    colours: dict[str, list[float | None]] = field(default_factory=dict)
    #: per score kind, the share of the best answer's surface its depth fit leaves unexplained
    #: (`Result.unexplained`; None: not measured, or answers collected before it was kept)
    unexplained: dict[str, list[float | None]] = field(default_factory=dict)

    @property
    def kinds(self) -> list[str]:
        return list(self.objects)

    def lists(self, kind: str) -> tuple[np.ndarray, np.ndarray]:
        """(object ids, distances), (n, LISTED) each, every row."""
        return np.array(self.objects[kind], int), np.array(self.distances[kind], float)

    def arrays(
        self, kind: str, statistic: Calibration | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(best answers' scores, right, registered, obj) of one score kind, refused queries left out; the
        score is `statistic`'s (`Calibration.values`, as the service computes it), else the distance."""
        ids, dist = self.lists(kind)
        keep = ids[:, 0] >= 0
        obj = np.array(self.obj)
        best = dist[:, 0] if statistic is None else best_values(ids, dist, statistic)
        if statistic is not None and (measure := term_of(statistic)) is not None:
            best = with_term(best, self.measured(kind, measure), statistic, measure)
        return best[keep], (ids[:, 0] == obj)[keep], np.array(self.registered)[keep], obj[keep]

    def measured(self, kind: str, measure: str) -> np.ndarray:
        """What the frames showed of the best answers (`service.rejection.MEASURES`: "colour", their colour
        distances; "fit", the share their depth fit leaves unexplained), nan where none was measured.
        Shape: (n,)."""
        got = (self.colours if measure == "colour" else self.unexplained).get(kind) or [None] * len(self.obj)
        return np.array([np.nan if c is None else c for c in got], float)

    def run_of(self, kind: str) -> np.ndarray:
        """Each answered row's registered set (the rows `arrays` keeps)."""
        return np.array(self.run)[self.lists(kind)[0][:, 0] >= 0]

    def save(self, path: Path) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.__dict__))

    @classmethod
    def load(cls, path: Path) -> Answers:
        return cls(**json.loads(path.read_text()))


def best_values(ids: np.ndarray, dist: np.ndarray, statistic: Calibration) -> np.ndarray:
    """The best answer's `statistic` of each row of answer lists ((n, LISTED) ids and distances), computed
    by the service's own code on the answers the service listed; nan for a refused query. The best is the
    answer listed first, its statistic read against the others nearest first, as the service judges them
    (`service.rejection.judge`) before the depth re-orders them (`service.pipeline.answer.shown`)."""
    out = np.full(len(ids), np.nan)
    for i, (row_ids, row_dist) in enumerate(zip(ids, dist, strict=True)):
        listed = [
            Match(int(o), "", 0.0, 0.0, 0.0, float(d))
            for o, d in zip(row_ids, row_dist, strict=True)
            if o >= 0
        ][:REJECT_LISTED]
        if listed:
            nearest = sorted(listed, key=lambda m: m.distance)  # stable: ties keep their order
            out[i] = statistic.values(nearest)[next(j for j, m in enumerate(nearest) if m is listed[0])]
    return out


def term_of(stat: Calibration) -> str | None:
    """The measure of `stat`'s term ("colour" or "fit"), None without one. A calibration holds one at most
    here: each moves the statistic onto its own threshold, and two would leave no one scale to find it on."""
    have = [m for m in MEASURES if stat.term(m) is not None]
    if len(have) > 1:
        raise ValueError(f"a calibration with both a colour and a fit term: {stat}")
    return have[0] if have else None


def with_term(best: np.ndarray, measured: np.ndarray, stat: Calibration, measure: str) -> np.ndarray:
    """The best answers' statistics as the service judges them with `stat`'s term of `measure`
    (`service.rejection.termed`): plus its weight times what was measured, on the term's threshold; where
    nothing was measured the statistic alone is judged on `stat.threshold`, so it is moved by the
    difference of the two thresholds (the same verdict on the term's scale)."""
    term = stat.term(measure)
    assert term is not None
    return np.where(np.isnan(measured), best - stat.threshold + term.threshold, best + term.weight * measured)


def decision_threshold(stat: Calibration) -> float:
    """What `Answers.arrays`'s statistics are judged on: the term's threshold when it has one."""
    measure = term_of(stat)
    term = None if measure is None else stat.term(measure)
    return stat.threshold if term is None else term.threshold


def score_kinds(embedder: Embedder) -> list[str]:
    """The kinds of score the service answers with for this model."""
    return ["local", "descriptor"] if embedder.has_local else ["descriptor"]


def collect(
    model: Path,
    dataset_dir: Path,
    frames: Sequence[int] | None,
    registered_sets: Sequence[Sequence[int]],
    scene: int | Sequence[int] = 2,
    min_visib: float = 0.5,
    settings: Settings | None = None,
    seed: int = 0,
) -> Answers:
    """Every instance of `frames` (None: all) of `scene` (or of each of several scenes: videos) through
    `recognise`, once per registered set (dataset object ids), with `settings` (default: the service's,
    `POSEDESC_*`) but rejection off."""
    dataset = BopDataset(dataset_dir)
    obj_ids = dataset.obj_ids
    scenes = [scene] if isinstance(scene, int) else list(scene)
    by_scene = [select_instances(dataset, s, min_visib, frames, obj_ids) for s in scenes]
    instances = [i for group in by_scene for i in group]
    if not instances:
        raise ValueError(f"{dataset_dir}: no instance of scene {scenes} in the frames asked for")
    with tempfile.TemporaryDirectory(prefix="posedesc-openset-") as tmp:
        base = Path(tmp) / "all"
        given = settings or Settings()
        settings = given.model_copy(update={"data_dir": base, "demo_objects": False, "reject_above": "off"})
        embedder = Embedder(model, settings.threads)
        kinds = score_kinds(embedder)
        state = load_state(settings, {embedder.modality: embedder})
        try:
            meshes, dataset_ids = register_objects(state, dataset, obj_ids)
            made = {k: settings_of(settings, embedder, k) for k in kinds}
        finally:
            close_state(state)
        store_id = {o: s for s, o in dataset_ids.items()}
        kind = served_data(embedder.modality, instances, None)
        renderer = Renderer() if kind in RENDERED else None  # this thread's (EGL: a context a thread)
        with closing(renderer) if renderer else nullcontext():
            sent = [  # a scene at a time: frame ids repeat across scenes
                f
                for group in by_scene
                for f in frame_files(dataset, group, embedder.modality, kind, seed, renderer, dict(meshes))
            ]
        out = Answers(
            objects={k: [] for k in kinds}, distances={k: [] for k in kinds}, settings=made, data=kind
        )
        with bar(len(registered_sets) * len(instances), "recognise (open set)") as b:
            for run, subset in enumerate(registered_sets):
                folder = Path(tmp) / f"run{run}"
                shutil.copytree(base, folder)
                state = load_state(replace_dir(settings, folder), {embedder.modality: embedder})
                try:
                    for o in set(obj_ids) - set(subset):
                        state.remove(store_id[o])
                    _ask(state, sent, dataset_ids, kinds, set(subset), run, out, b.update)
                finally:
                    close_state(state)
                shutil.rmtree(folder)
    return out


def replace_dir(settings: Settings, data_dir: Path) -> Settings:
    return settings.model_copy(update={"data_dir": data_dir})


def _ask(state: AppState, sent, dataset_ids, kinds, subset: set[int], run: int, out: Answers, tick) -> None:
    with_local = state.settings
    without = with_local.model_copy(update={"rerank": 0})
    for group, rgb, depth, scale in sent:
        for inst in group:
            out.obj.append(inst.obj_id)
            out.registered.append(inst.obj_id in subset)
            out.run.append(run)
            out.frame.append(inst.frame_id)
            out.scene.append(inst.scene_id)
            q = replace(query(inst, rgb, depth, scale), k=LISTED)
            for kind in kinds:
                state.settings = with_local if kind == "local" else without
                try:
                    result = recognise(state, q)
                except ApiError:  # refused: counted apart, not as an answer
                    result = None
                ids, dist = [-1] * LISTED, [float("nan")] * LISTED
                colour = unexplained = None
                if result is not None and result.score == kind:
                    for i, m in enumerate(result.matches[:LISTED]):
                        ids[i], dist[i] = dataset_ids[m.object_id], float(m.distance)
                    colour = result.colour_distance
                    unexplained = result.unexplained
                out.objects[kind].append(ids)
                out.distances[kind].append(dist)
                out.colours.setdefault(kind, []).append(colour)
                out.unexplained.setdefault(kind, []).append(unexplained)
            state.settings = with_local
            tick()


def kinds_of(
    a: Answers, kind: str, stat: Calibration | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scores of (right, wrong, unknown) best answers (`stat`'s statistic, else the distance)."""
    s, right, reg, _ = a.arrays(kind, stat)
    return s[reg & right], s[reg & ~right], s[~reg]


def calibrate(
    a: Answers, stat: Calibration, rule: tuple[str, float], frames: str
) -> tuple[Calibration, dict]:
    """`stat`'s threshold by `rule` ("registered": reject at most that share of the registered objects'
    patches, right or wrong; "right": keep that share of the right answers) and its confidence curve."""
    plain = replace(stat, colour=None, fit=None)
    threshold, slope, midpoint, report = _fitted(*kinds_of(a, stat.score, plain), rule)
    cal = replace(plain, threshold=at_least(threshold), slope=round(slope, 5), midpoint=round(midpoint, 5),
                  frames=frames, settings=a.settings[stat.score])  # fmt: skip
    return cal, report


def calibrate_term(
    a: Answers, cal: Calibration, measure: str, weight: float, rule: tuple[str, float]
) -> tuple[Calibration, dict]:
    """`cal` (calibrated, without a term) with a term of `measure` ("colour" or "fit") of this `weight`
    (`service.rejection.Term`): its threshold by `rule` and its confidence curve on the best answers'
    statistics plus `weight` times what was measured of them. Answers without it count at their statistic
    moved onto the term's scale (`with_term`), which needs the term's threshold: found again from the last
    until it stands."""
    term = Term(weight, cal.threshold, 0.0, 0.0)
    for _ in range(5):
        threshold, slope, midpoint, report = _fitted(
            *kinds_of(a, cal.score, cal.with_term(measure, term)), rule
        )
        moved = abs(threshold - term.threshold) > 1e-9
        term = Term(weight, at_least(threshold), round(slope, 5), round(midpoint, 5))
        if not moved:
            break
    return cal.with_term(measure, term), report


def _fitted(
    right: np.ndarray, wrong: np.ndarray, unknown: np.ndarray, rule: tuple[str, float]
) -> tuple[float, float, float, dict]:
    """The threshold `rule` gives on these best answers' statistics (right, wrong: registered objects';
    unknown: unregistered ones'), the logistic curve of "the right object" on them, and the report."""
    name, share = rule
    registered = np.concatenate([right, wrong])
    threshold = keep_threshold(registered if name == "registered" else right, 1 - share if name ==
                               "registered" else share)  # fmt: skip
    s = np.concatenate([right, wrong, unknown])
    label = np.concatenate([np.ones(len(right)), np.zeros(len(wrong) + len(unknown))])
    n_reg, n_unk = len(right) + len(wrong), len(unknown)
    # registered and unregistered patches weigh half each: the confidence assumes a 1 in 2 chance of an
    # object that is not registered, whatever the numbers of each the calibration happened to have
    w = np.concatenate([np.full(n_reg, 0.5 / n_reg), np.full(n_unk, 0.5 / n_unk)]) * len(s)
    slope, midpoint = fit_logistic(s, label, w)
    grid = np.quantile(s, np.linspace(0, 1, 101))
    report = {
        "n": {"right": len(right), "wrong": len(wrong), "unknown": n_unk},
        "median": {"right": _med(right), "wrong": _med(wrong), "unknown": _med(unknown)},
        "at_threshold": _at(right, wrong, unknown, at_least(threshold)),
        "curve": rejection_curve(right, wrong, unknown, grid),
    }
    return threshold, slope, midpoint, report


#: the statistics compared on validation frames (`explore`): the distance, and the lead at these weights
LEAD_WEIGHTS = (0.25, 0.5, 1.0, 2.0, 4.0)
#: the colour term's weights compared (`explore`), on the lead at weight `COLOUR_LEAD` (the shipped statistic)
COLOUR_WEIGHTS = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0)
COLOUR_LEAD = 2.0
#: the fit term's weights compared (`explore`), on the lead at weight `FIT_LEAD` (the depth model's statistic)
FIT_WEIGHTS = (0.05, 0.1, 0.15, 0.2, 0.3, 0.4)
FIT_LEAD = 0.5
#: the exploration's figure: the unknowns rejected where at most this share of registered patches is
EXPLORE_AT = 0.1


def explore(a: Answers, kind: str) -> list[dict]:
    """Candidate statistics on the validation answers, best first: the share of unregistered objects'
    patches rejected (pooled, and the worst object) at the threshold that rejects at most `EXPLORE_AT` of
    the registered objects' patches, the right answers rejected there, and the area under the ROC curve
    (unknown against registered). Shippable ones are computed by the service's code (`Calibration`);
    the others from the answer lists here, to see whether they would be worth shipping."""
    ids, dist = a.lists(kind)
    answered = ids[:, 0] >= 0
    ids, dist = ids[answered], dist[answered]
    _, right, reg, obj = a.arrays(kind)
    stats: dict[str, np.ndarray] = {"distance": dist[:, 0]}
    for w in LEAD_WEIGHTS:
        stats[f"lead, weight {w:g}"] = a.arrays(kind, Calibration(kind, 0, 0, 0, statistic="lead", weight=w))[
            0
        ]
    other = _nearest_other(ids, dist)
    stats["ratio: distance / nearest other object's"] = dist[:, 0] / other
    stats["minus the lead alone"] = dist[:, 0] - other
    for n in (5, 10):
        stats[f"share of the top {n} not the best's object"] = 1 - (ids[:, :n] == ids[:, :1]).mean(1)
    colour = a.measured(kind, "colour")[answered]
    if not np.isnan(colour).all():  # the colours at the best answer's pose (`service.pipeline.colours`)
        for c in COLOUR_WEIGHTS:
            lead = stats[f"lead, weight {COLOUR_LEAD:g}"]
            stats[f"lead, weight {COLOUR_LEAD:g}, + {c:g} x the colour distance"] = lead + c * np.nan_to_num(
                colour
            )
    unexplained = a.measured(kind, "fit")[answered]
    if not np.isnan(
        unexplained
    ).all():  # the depth at the best answer's pose (`service.pipeline.unexplained`)
        for c in FIT_WEIGHTS:
            lead = stats[f"lead, weight {FIT_LEAD:g}"]
            stats[f"lead, weight {FIT_LEAD:g}, + {c:g} x the unexplained share"] = lead + c * np.nan_to_num(
                unexplained
            )
    if kind == "local" and "descriptor" in a.kinds:  # not shippable: the re-ranking drops the descriptor's
        d = a.lists("descriptor")[1][answered, 0]
        for w in (5.0, 10.0):
            stats[f"distance + {w:g} x the descriptor run's best distance (offline)"] = dist[:, 0] + w * d
    rows = []
    for name, s in stats.items():
        t = keep_threshold(s[reg], 1 - EXPLORE_AT)
        per = [float(np.mean(s[~reg & (obj == o)] > t)) for o in np.unique(obj[~reg])]
        rows.append({
            "statistic": name,
            "unknown_rejected": round(float(np.mean(s[~reg] > t)), 4),
            "worst_object": round(min(per), 4),
            "registered_rejected": round(float(np.mean(s[reg] > t)), 4),
            "right_rejected": round(float(np.mean(s[reg & right] > t)), 4),
            "auc": round(auc(s[~reg], s[reg]), 4),
        })  # fmt: skip
    return sorted(rows, key=lambda r: -r["unknown_rejected"])


def _nearest_other(ids: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Each row's nearest answer of another object than the best's (the last listed when none)."""
    differ = (ids != ids[:, :1]) & (ids >= 0)
    first = dist[np.arange(len(ids)), np.argmax(differ, 1)]
    return np.where(differ.any(1), first, np.nanmax(dist, 1))


def compare_filtered(a: Answers, kind: str, stat: Calibration) -> dict:
    """How well one collection with every object registered stands in for the left-out runs: each object's
    left-out answer taken as the best listed answer of another object in the all-registered run (run 0),
    against the exact run without it (the same patch): the same object answered, and the statistic."""
    ids, dist = a.lists(kind)
    run, obj = np.array(a.run), np.array(a.obj)
    frame = list(zip(a.scene or [0] * len(a.run), a.frame, strict=True))  # frame ids repeat across scenes
    full = {(f, o): i for i, (r, f, o) in enumerate(zip(run, frame, obj, strict=True)) if r == 0}
    same, diffs = [], []
    for r in range(1, max(run) + 1):
        gone = set(obj) - {o for o, reg_, rr in zip(obj, a.registered, run, strict=True) if reg_ and rr == r}
        for i in np.flatnonzero(run == r):
            j = full.get((frame[i], obj[i]))
            if j is None or ids[i, 0] < 0 or ids[j, 0] < 0:
                continue
            keep = ~np.isin(ids[j], list(gone)) & (ids[j] >= 0)
            if not keep.any():
                continue
            fi, fd = ids[j][keep][None], dist[j][keep][None]
            same.append(fi[0, 0] == ids[i, 0])
            approx = best_values(fi, fd, stat)[0]
            exact = best_values(ids[i : i + 1], dist[i : i + 1], stat)[0]
            diffs.append(approx - exact)
    d = np.array(diffs)
    return {
        "n": len(same),
        "same_object": round(float(np.mean(same)), 4),
        "statistic_difference": {"median": round(float(np.median(d)), 5),
                                 "median_abs": round(float(np.median(np.abs(d))), 5),
                                 "p90_abs": round(float(np.quantile(np.abs(d), 0.9)), 5)},
    }  # fmt: skip


def _med(x: np.ndarray) -> float | None:
    return round(float(np.median(x)), 4) if len(x) else None


def _at(right, wrong, unknown, t: float) -> dict:
    def share(x):
        return round(float(np.mean(x > t)), 4) if len(x) else None

    reg = np.concatenate([right, wrong])
    return {
        "rejected_unknown": share(unknown),
        "rejected_registered": share(reg),
        "rejected_right": share(right),
        "rejected_wrong": share(wrong),
    }


def measure(a: Answers, cal: Calibration, sets: list[list[int]], fold: int = 1) -> dict:
    """The calibration on held-out answers: per left-out object (in the runs without it and `fold` - 1
    others, `registered_sets`), and by how many objects were registered."""
    s, right, reg, obj = a.arrays(cal.score, cal)
    t = decision_threshold(cal)
    run = a.run_of(cal.score)
    out: dict = {"per_unregistered_object": {}, "by_registered": {}}
    left_out = [r for r, subset in enumerate(sets) if len(subset) == len(sets[0]) - fold]
    for gone in sorted(set(a.obj)):
        m = np.isin(run, [r for r in left_out if gone not in sets[r]]) & ((obj == gone) | reg)
        out["per_unregistered_object"][str(gone)] = {
            "n": int((m & ~reg).sum()),
            "n_registered": int((m & reg).sum()),
            **_at(s[m & reg & right], s[m & reg & ~right], s[m & ~reg], t),
        }
    for n in sorted({len(x) for x in sets}):
        m = np.isin(run, [r for r, x in enumerate(sets) if len(x) == n])
        out["by_registered"][str(n)] = {
            "runs": sum(len(x) == n for x in sets),
            "n_registered": int((m & reg).sum()),
            "n_unknown": int((m & ~reg).sum()),
            "recognised": round(float(right[m & reg].mean()), 4) if (m & reg).any() else None,
            "median": {
                "right": _med(s[m & reg & right]),
                "wrong": _med(s[m & reg & ~right]),
                "unknown": _med(s[m & ~reg]),
            },
            **_at(s[m & reg & right], s[m & reg & ~right], s[m & ~reg], t),
            "curve": rejection_curve(
                s[m & reg & right], s[m & reg & ~right], s[m & ~reg], np.quantile(s, np.linspace(0, 1, 101))
            ),
        }
    return out


def registered_sets(
    obj_ids: list[int], sizes: list[int], per_size: int, seed: int, fold: int = 1
) -> list[list[int]]:
    """Every object registered, each left out in turn (with `fold` - 1 others: every `fold`-th object of
    the list out at once, so that a dataset of many objects needs fewer runs), and `per_size` random sets of
    each size below that."""
    rng = np.random.default_rng(seed)
    groups = max(1, -(-len(obj_ids) // fold))
    sets = [list(obj_ids)] + [[o for o in obj_ids if o not in obj_ids[g::groups]] for g in range(groups)]
    for n in sizes:
        if n < len(obj_ids) - fold:
            sets += [sorted(rng.choice(obj_ids, n, replace=False).tolist()) for _ in range(per_size)]
    return sets
