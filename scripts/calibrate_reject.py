"""Calibrate a model's open-set rejection ("no registered object") and write it into its metadata.

    PYTHONPATH=. .venv/bin/python scripts/calibrate_reject.py models/posedesc-rgb.onnx \
        --dataset ../shared/data/lmo --statistic local=lead:2 --statistic descriptor=lead:1 \
        --out models/posedesc-rgb.onnx

On the model's validation frames (its `split_frames` metadata, or `--splits-from` another model's within
`--held-out`), through the service protocol with the service's settings (`POSEDESC_*`; `evaluation.openset`):
every object registered, then each object in turn left unregistered. For each kind of score the service
answers with (the local distance with re-ranking, the descriptor distance without), the statistic asked for
(`--statistic`: the best answer's distance, or its "lead", `service.rejection`) gets the threshold that
rejects at most `--reject-registered` of the registered objects' patches (or keeps `--keep-right` of the right
answers), and a logistic fit of "the best answer is the right object" on it gives the confidence. They go
into the model's `reject_above` metadata with the settings the answers were made with: only
`metadata_props` is rewritten (the onnx package), the graph and weights are left byte for byte as they were.
The answers are kept in `--cache` (out/openset), read again while the frames, sets and settings are the same.

The JSON (docs/results/reject-<model>.json) also holds, on validation, the statistics tried (`explore`: the
unregistered objects' patches rejected where at most 10 % of the registered ones are) and how one collection
with every object registered, filtered, stands in for the left-out runs (`compare_filtered`). Then, on the
held-out test frames, it measures the calibration: with each object in turn unregistered, the share of its
patches answered "unknown", of the registered objects' patches and of the right answers rejected; and with
3, 5 and all-but-one objects registered, how the unknowns' scores move as objects are added. A picture goes
to docs/.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.calibration import (  # noqa: E402
    fit_logistic,
    keep_threshold,
    rejection_curve,
)
from evaluation.openset import Answers, best_values, collect  # noqa: E402
from evaluation.splits import split_frames  # noqa: E402
from index.data.bop import BopDataset  # noqa: E402
from index.features.embed import Embedder  # noqa: E402
from posedesc.commands.evaluate import parse_ids  # noqa: E402
from service.rejection import REJECT_KEY, SCORE_KINDS, STATISTICS, Calibration  # noqa: E402
from service.settings import Settings  # noqa: E402


def kinds_of(a: Answers, kind: str, stat: Calibration | None = None) -> tuple[np.ndarray, ...]:
    """Scores of (right, wrong, unknown) best answers (`stat`'s statistic, else the distance)."""
    s, right, reg, _ = a.arrays(kind, stat)
    return s[reg & right], s[reg & ~right], s[~reg]


def calibrate(
    a: Answers, stat: Calibration, rule: tuple[str, float], frames: str
) -> tuple[Calibration, dict]:
    """`stat`'s threshold by `rule` ("registered": reject at most that share of the registered objects'
    patches, right or wrong; "right": keep that share of the right answers) and its confidence curve."""
    right, wrong, unknown = kinds_of(a, stat.score, stat)
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
    cal = replace(stat, threshold=round(threshold, 5), slope=round(slope, 5), midpoint=round(midpoint, 5),
                  frames=frames, settings=a.settings[stat.score])  # fmt: skip
    grid = np.quantile(s, np.linspace(0, 1, 101))
    report = {
        "n": {"right": len(right), "wrong": len(wrong), "unknown": n_unk},
        "median": {"right": _med(right), "wrong": _med(wrong), "unknown": _med(unknown)},
        "at_threshold": _at(right, wrong, unknown, cal.threshold),
        "curve": rejection_curve(right, wrong, unknown, grid),
    }
    return cal, report


#: the statistics compared on validation frames (`explore`): the distance, and the lead at these weights
LEAD_WEIGHTS = (0.25, 0.5, 1.0, 2.0, 4.0)
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
            "auc": round(_auc(s[~reg], s[reg]), 4),
        })  # fmt: skip
    return sorted(rows, key=lambda r: -r["unknown_rejected"])


def _nearest_other(ids: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Each row's nearest answer of another object than the best's (the last listed when none)."""
    differ = (ids != ids[:, :1]) & (ids >= 0)
    first = dist[np.arange(len(ids)), np.argmax(differ, 1)]
    return np.where(differ.any(1), first, np.nanmax(dist, 1))


def _auc(high: np.ndarray, low: np.ndarray) -> float:
    """P(a `high` score above a `low` one), ties half."""
    low = np.sort(low)
    below = np.searchsorted(low, high, "left")
    ties = np.searchsorted(low, high, "right") - below
    return float((below + ties / 2).sum() / (len(high) * len(low)))


def compare_filtered(a: Answers, kind: str, stat: Calibration) -> dict:
    """How well one collection with every object registered stands in for the left-out runs: each object's
    left-out answer taken as the best listed answer of another object in the all-registered run (run 0),
    against the exact run without it (the same patch): the same object answered, and the statistic."""
    ids, dist = a.lists(kind)
    run, frame, obj = np.array(a.run), np.array(a.frame), np.array(a.obj)
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


def measure(a: Answers, cal: Calibration, sets: list[list[int]]) -> dict:
    """The calibration on held-out answers: per left-out object, and by how many objects were registered."""
    s, right, reg, obj = a.arrays(cal.score, cal)
    t = cal.threshold
    run = a.run_of(cal.score)
    out: dict = {"per_unregistered_object": {}, "by_registered": {}}
    for r, subset in enumerate(sets):
        if len(subset) != len(set(a.obj)) - 1:
            continue
        gone = (set(a.obj) - set(subset)).pop()
        m = run == r
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


def registered_sets(obj_ids: list[int], sizes: list[int], per_size: int, seed: int) -> list[list[int]]:
    """Every object registered, each left out in turn, and `per_size` random sets of each size."""
    rng = np.random.default_rng(seed)
    sets = [list(obj_ids)] + [[o for o in obj_ids if o != x] for x in obj_ids]
    for n in sizes:
        if n < len(obj_ids) - 1:
            sets += [sorted(rng.choice(obj_ids, n, replace=False).tolist()) for _ in range(per_size)]
    return sets


def write_metadata(model: Path, out: Path, calibrations: dict[str, dict]) -> None:
    """The model with its `reject_above` metadata replaced: only metadata_props changes."""
    import onnx

    proto = onnx.load(str(model))
    graph = proto.graph.SerializeToString()
    props = {p.key: p.value for p in proto.metadata_props}
    props[REJECT_KEY] = json.dumps(calibrations)
    del proto.metadata_props[:]
    for k, v in props.items():
        proto.metadata_props.add(key=k, value=v)
    onnx.save(proto, str(out))
    if onnx.load(str(out)).graph.SerializeToString() != graph:
        raise SystemExit(f"{out}: the graph changed while writing the metadata")


def picture(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = list(report["calibrations"])
    fig, axes = plt.subplots(len(kinds), 2, figsize=(11, 4.2 * len(kinds)), squeeze=False)
    for row, kind in zip(axes, kinds, strict=True):
        cal, test = report["calibrations"][kind], report["test"].get(kind, {})
        t = cal["threshold"]
        for name, colour in (("right", "tab:green"), ("wrong", "tab:orange"), ("unknown", "tab:red")):
            xs = report["val_scores"][kind][name]
            if xs:
                row[0].hist(xs, bins=30, alpha=0.5, color=colour, density=True, label=f"{name} ({len(xs)})")
        row[0].axvline(t, color="k", ls="--", label=f"threshold {t:.3g}")
        row[0].set_xlabel(
            f"best answer's {Calibration(kind, t, 0, 0, statistic=cal['statistic'], weight=cal['weight']).describe()}"
        )
        row[0].set_title(f"validation frames ({kind}): best answers' scores")
        row[0].legend(fontsize=8)
        for n, by in test.get("by_registered", {}).items():
            if not by["n_unknown"]:
                continue  # every object registered: no unknowns to reject
            c = by["curve"]
            row[1].plot(c["rejected_unknown"], c["recall"], label=f"{n} registered")
            row[1].plot(by["rejected_unknown"], 1 - by["rejected_right"], "ko", ms=4)
        row[1].set_xlabel("patches of unregistered objects rejected")
        row[1].set_ylabel("right answers kept")
        row[1].set_title(f"test frames ({kind}); dots: the calibrated threshold")
        row[1].grid(alpha=0.3)
        row[1].legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)


#: the default rule: reject at most this share of the registered objects' validation patches. Below the
#: 10 % aimed at on new frames: the rgb threshold of "keep 0.9 of right answers" on validation rejected 13.6 %
#: of the registered objects' patches of the test frames
REJECT_REGISTERED = 0.08


def statistics(given: list[str]) -> dict[str, tuple[str, float]]:
    """--statistic values: score kind ("" for every one) -> (statistic, weight)."""
    out = {}
    for text in given:
        kind, _, what = text.rpartition("=")
        name, _, weight = what.partition(":")
        if kind not in ("", *SCORE_KINDS) or name not in STATISTICS or (name == "lead") != bool(weight):
            raise ValueError(
                f"{text!r}: 'distance' or 'lead:WEIGHT', optionally after 'local=' or 'descriptor='"
            )
        out[kind] = (name, float(weight or 0.0))
    return out


def frames_of(args: argparse.Namespace, meta: dict[str, str]) -> tuple[list[int], list[int]]:
    """(validation, test) frames: the model's `split_frames`, or those of `--splits-from` (a model trained
    with the same data) kept within `--held-out` (the frames this model was not trained on)."""
    if args.splits_from is not None:
        meta = Embedder(args.splits_from).info.extra
    val = split_frames(meta, args.dataset, args.scene, "val") or []
    test = split_frames(meta, args.dataset, args.scene, "test") or []
    if args.held_out:
        kept = set(parse_ids(args.held_out))
        val, test = [f for f in val if f in kept], [f for f in test if f in kept]
    return val, test


def answers(args: argparse.Namespace, split: str, frames: list[int], sets: list[list[int]]) -> Answers:
    """The split's answers: read from `--cache` when they were collected with the same frames, sets and
    settings, else collected (`evaluation.openset.collect`) and written there."""
    path = args.cache / f"{args.model.stem}-{split}.json"
    key = {"frames": frames, "sets": sets, "settings": Settings().model_dump(mode="json")}
    if path.is_file():
        cached = json.loads(path.read_text())
        if cached.get("key") == key:
            return Answers(**cached["answers"])
    a = collect(args.model, args.dataset, frames, sets, args.scene, seed=args.seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"key": key, "answers": a.__dict__}))
    return a


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", type=Path)
    ap.add_argument("--dataset", type=Path, required=True, help="BOP dataset folder")
    ap.add_argument("--scene", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="model file to write (default: none)")
    ap.add_argument("--json", type=Path, default=None, help="default docs/results/reject-<model>.json")
    ap.add_argument("--picture", type=Path, default=None, help="default docs/reject-<model>.png")
    ap.add_argument("--cache", type=Path, default=ROOT / "out" / "openset", help="collected answers")
    ap.add_argument("--splits-from", type=Path, default=None,
                    help="a model whose split_frames to use (this one has none)")  # fmt: skip
    ap.add_argument("--held-out", default="", help="keep only these frames (e.g. 258-435,808-942)")
    ap.add_argument("--statistic", action="append", default=[], help="what to threshold: 'distance' or "
                    "'lead:WEIGHT', for every score kind or one ('local=lead:2'); default distance")  # fmt: skip
    ap.add_argument(
        "--reject-registered",
        type=float,
        default=REJECT_REGISTERED,
        help="reject at most this share of the registered objects' validation patches",
    )
    ap.add_argument("--keep-right", type=float, default=None, help="instead: keep this share of right "
                    "answers")  # fmt: skip
    ap.add_argument("--sizes", default="3,5", help="test: registered-set sizes besides all-but-one")
    ap.add_argument("--per-size", type=int, default=3, help="test: random registered sets per size")
    ap.add_argument("--no-test", action="store_true", help="calibrate only")
    ap.add_argument("--collect-only", action="store_true", help="collect (or read) the answers, no more")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if not args.model.is_file():
        sys.exit(f"no such model: {args.model}")
    if not (args.dataset / "models").is_dir():
        sys.exit(f"not a BOP dataset: {args.dataset}")
    if args.keep_right is not None and not 0 < args.keep_right <= 1:
        sys.exit("--keep-right: a share in (0, 1]")
    try:
        chosen = statistics(args.statistic)
    except ValueError as e:
        sys.exit(f"--statistic: {e}")
    if not 0 <= args.reject_registered < 1:
        sys.exit("--reject-registered: a share in [0, 1)")
    embedder = Embedder(args.model)
    val, test = frames_of(args, embedder.info.extra)
    if not val:
        sys.exit(f"{args.model} names no val frames of {args.dataset.name} scene {args.scene} (split_frames)")
    objects = BopDataset(args.dataset).obj_ids
    sizes = [int(x) for x in args.sizes.split(",") if x.strip()]
    val_sets = registered_sets(objects, [], 0, args.seed)
    test_sets = registered_sets(objects, sizes, args.per_size, args.seed)
    a = answers(args, "val", val, val_sets)
    t = answers(args, "test", test, test_sets) if test and not args.no_test else None
    if args.collect_only:
        return
    rule = ("right", args.keep_right) if args.keep_right else ("registered", args.reject_registered)
    stem = args.model.stem
    dataset = f"{args.dataset.resolve().name}/{args.scene:06d}"
    report: dict = {
        "model": str(args.model), "dataset": dataset, "objects": objects, "data": a.data,
        "command": " ".join(["scripts/calibrate_reject.py", *sys.argv[1:]]),
        "frames": {"val": val, "test": test},
        "rule": f"keep {rule[1]} of right answers" if rule[0] == "right" else
        f"reject at most {rule[1]} of the registered objects' validation patches",
        "calibrations": {}, "explored": {}, "compare_filtered": {}, "val_scores": {}, "test": {},
    }  # fmt: skip
    metadata = {}
    for kind in a.kinds:
        name, weight = chosen.get(kind, chosen.get("", ("distance", 0.0)))
        stat = Calibration(kind, 0.0, 0.0, 0.0, statistic=name, weight=weight)
        cal, rep = calibrate(a, stat, rule, "val")
        metadata[kind] = {**cal.to_json(), "dataset": dataset, "objects": len(objects), "rule": report["rule"],
                          "data": a.data}  # fmt: skip
        report["calibrations"][kind] = {**metadata[kind], **rep}
        report["explored"][kind] = explore(a, kind)
        report["compare_filtered"][kind] = compare_filtered(a, kind, cal)
        report["val_scores"][kind] = {k: np.round(v, 4).tolist() for k, v in zip(
            ("right", "wrong", "unknown"), kinds_of(a, kind, cal), strict=True)}  # fmt: skip
        print(f"{kind}: {cal.describe()} threshold {cal.threshold:.4g}, val {rep['at_threshold']}")
        for row in report["explored"][kind]:
            print(f"  explored {kind}: {json.dumps(row)}")
        print(f"  one collection filtered against left-out runs: {report['compare_filtered'][kind]}")
        if t is not None:
            report["test"][kind] = measure(t, cal, test_sets)
            for o, by in report["test"][kind]["per_unregistered_object"].items():
                print(f"{kind} test, object {o} unregistered: {json.dumps(by)}")
    report["test_sets"] = test_sets
    json_path = args.json or ROOT / "docs" / "results" / f"reject-{stem}.json"
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(report, indent=1) + "\n")
    picture(report, args.picture or ROOT / "docs" / f"reject-{stem}.png")
    if args.out is not None:
        write_metadata(args.model, args.out, metadata)
        print(f"wrote {REJECT_KEY} into {args.out}")
    print(f"wrote {json_path}")


if __name__ == "__main__":
    main()
