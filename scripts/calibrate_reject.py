"""Calibrate a model's open-set rejection ("no registered object") and write it into its metadata.

    PYTHONPATH=. .venv/bin/python scripts/calibrate_reject.py models/posedesc-rgb.onnx \
        --dataset ../shared/data/lmo --out models/posedesc-rgb.onnx

On the model's validation frames (its `split_frames` metadata), through the service protocol
(`evaluation.openset`): every object registered, then each object in turn left unregistered. For each kind
of score the service answers with (the local distance with re-ranking, the descriptor distance without),
the threshold is the one that best separates the best answers that are the right object from those to
patches of unregistered objects (Youden's J; or `--keep-right`), and a logistic fit of "the best answer is
the right object" on the score gives the confidence (`service.rejection`). They go into the model's
`reject_above` metadata: only `metadata_props` is rewritten (the onnx package), the graph and weights are
left byte for byte as they were.

Then, on the held-out test frames, it measures the threshold: with each object in turn unregistered, the
share of its patches answered "unknown" and the share of the registered objects' patches rejected; and with
3, 5 and all-but-one objects registered, how the unknowns' scores move as objects are added. The JSON of the
curves goes to docs/results/, a picture to docs/.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.calibration import (  # noqa: E402
    fit_logistic,
    keep_threshold,
    rejection_curve,
    youden_threshold,
)
from evaluation.openset import Answers, collect, score_kinds  # noqa: E402
from index.bop import BopDataset  # noqa: E402
from index.embed import Embedder  # noqa: E402
from posedesc.commands.evaluate import split_frames  # noqa: E402
from service.rejection import REJECT_KEY, Calibration  # noqa: E402


def kinds_of(a: Answers, kind: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scores of (right, wrong, unknown) best answers."""
    s, right, reg, _ = a.arrays(kind)
    return s[reg & right], s[reg & ~right], s[~reg]


def calibrate(a: Answers, kind: str, keep_right: float | None, frames: str) -> tuple[Calibration, dict]:
    right, wrong, unknown = kinds_of(a, kind)
    threshold = keep_threshold(right, keep_right) if keep_right else youden_threshold(right, unknown)
    s = np.concatenate([right, wrong, unknown])
    label = np.concatenate([np.ones(len(right)), np.zeros(len(wrong) + len(unknown))])
    n_reg, n_unk = len(right) + len(wrong), len(unknown)
    # registered and unregistered patches weigh half each: the confidence assumes a 1 in 2 chance of an
    # object that is not registered, whatever the numbers of each the calibration happened to have
    w = np.concatenate([np.full(n_reg, 0.5 / n_reg), np.full(n_unk, 0.5 / n_unk)]) * len(s)
    slope, midpoint = fit_logistic(s, label, w)
    cal = Calibration(kind, round(threshold, 5), round(slope, 5), round(midpoint, 5), frames)
    grid = np.quantile(s, np.linspace(0, 1, 101))
    report = {
        "n": {"right": len(right), "wrong": len(wrong), "unknown": n_unk},
        "median": {"right": _med(right), "wrong": _med(wrong), "unknown": _med(unknown)},
        "at_threshold": _at(right, wrong, unknown, threshold),
        "curve": rejection_curve(right, wrong, unknown, grid),
    }
    return cal, report


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


def measure(a: Answers, kind: str, t: float, sets: list[list[int]]) -> dict:
    """The threshold on held-out answers: per left-out object, and by how many objects were registered."""
    s, right, reg, obj = a.arrays(kind)
    run = np.array(a.run)[np.array(a.answered[kind]) >= 0]
    out: dict = {"per_unregistered_object": {}, "by_registered": {}}
    for r, subset in enumerate(sets):
        if len(subset) != len(set(a.obj)) - 1:
            continue
        gone = (set(a.obj) - set(subset)).pop()
        m = run == r
        out["per_unregistered_object"][str(gone)] = {
            "n": int((m & ~reg).sum()),
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
        row[0].set_xlabel(f"best answer's {kind} distance")
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", type=Path)
    ap.add_argument("--dataset", type=Path, required=True, help="BOP dataset folder")
    ap.add_argument("--scene", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="model file to write (default: none)")
    ap.add_argument("--json", type=Path, default=None, help="default docs/results/reject-<model>.json")
    ap.add_argument("--picture", type=Path, default=None, help="default docs/reject-<model>.png")
    ap.add_argument("--rerank", type=int, default=200, help="the service's RERANK the local score comes from")
    ap.add_argument("--keep-right", type=float, default=None, help="keep this share of right answers "
                    "(default: Youden's J between right answers and unregistered objects)")  # fmt: skip
    ap.add_argument("--sizes", default="3,5", help="test: registered-set sizes besides all-but-one")
    ap.add_argument("--per-size", type=int, default=3, help="test: random registered sets per size")
    ap.add_argument("--no-test", action="store_true", help="calibrate only")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if not args.model.is_file():
        sys.exit(f"no such model: {args.model}")
    if not (args.dataset / "models").is_dir():
        sys.exit(f"not a BOP dataset: {args.dataset}")
    if args.keep_right is not None and not 0 < args.keep_right <= 1:
        sys.exit("--keep-right: a share in (0, 1]")
    embedder = Embedder(args.model)
    meta = embedder.info.extra
    val = split_frames(meta, args.dataset, args.scene, "val")
    test = split_frames(meta, args.dataset, args.scene, "test")
    if not val:
        sys.exit(f"{args.model} names no val frames of {args.dataset.name} scene {args.scene} (split_frames)")
    objects = BopDataset(args.dataset).obj_ids
    stem = args.model.stem
    kinds = score_kinds(embedder)

    a = collect(args.model, args.dataset, val, registered_sets(objects, [], 0, args.seed), args.scene,
                rerank=args.rerank, seed=args.seed)  # fmt: skip
    report: dict = {"model": str(args.model), "dataset": f"{args.dataset.resolve().name}/{args.scene:06d}",
                    "rerank": args.rerank, "objects": objects,
                    "rule": f"keep {args.keep_right} of right answers" if args.keep_right else "Youden's J "
                    "(right answers kept minus unregistered objects' patches accepted)",
                    "calibrations": {}, "val_scores": {}, "test": {}}  # fmt: skip
    metadata = {}
    for kind in kinds:
        cal, rep = calibrate(a, kind, args.keep_right, "val")
        metadata[kind] = {
            **cal.to_json(),
            "dataset": report["dataset"],
            "rerank": args.rerank if kind == "local" else 0,
            "objects": len(objects),
            "rule": report["rule"],
        }
        report["calibrations"][kind] = {**metadata[kind], **rep}
        report["val_scores"][kind] = {k: np.round(v, 4).tolist() for k, v in zip(
            ("right", "wrong", "unknown"), kinds_of(a, kind), strict=True)}  # fmt: skip
        print(f"{kind}: threshold {cal.threshold:.4g}, val {rep['at_threshold']}")
    if test and not args.no_test:
        sizes = [int(x) for x in args.sizes.split(",") if x.strip()]
        sets = registered_sets(objects, sizes, args.per_size, args.seed)
        t = collect(args.model, args.dataset, test, sets, args.scene, rerank=args.rerank, seed=args.seed)
        report["test_sets"] = sets
        for kind in kinds:
            report["test"][kind] = measure(t, kind, metadata[kind]["threshold"], sets)
            for n, by in report["test"][kind]["by_registered"].items():
                print(f"{kind} test, {n} registered: " + json.dumps({k: by[k] for k in by if k != "curve"}))
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
