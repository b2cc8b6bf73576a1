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
The answers are kept in `--cache` (out/openset), read again while the frames, sets, settings and code are the same.
With `--leave-one-video-out` (a dataset of videos, such as YCB-V's), every video is measured with the
calibration chosen on the others and the JSON's test figures are the mean over the videos
(`evaluation.videos`); the calibration written (`--out`) is chosen on every video. With `--choose-weights` too,
the statistic itself (the lead's weight and the fit term's) is chosen per video on the others and measured on
it (`weights_left_out` in the JSON; `evaluation.videos.weights_by_video`).

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
import shutil
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from evaluation.calibration import code_digest  # noqa: E402
from evaluation.calibration import write_metadata as write_model_metadata  # noqa: E402
from evaluation.openset import (  # noqa: E402
    Answers,
    calibrate,
    calibrate_term,
    collect,
    compare_filtered,
    decision_threshold,
    explore,
    kinds_of,
    measure,
    registered_sets,
    term_of,
)
from evaluation.splits import split_frames  # noqa: E402
from evaluation.videos import mean_of, of_videos, weights_by_video  # noqa: E402
from index.data.bop import BopDataset  # noqa: E402
from index.features.embed import Embedder, graph_digest  # noqa: E402
from posedesc.commands.evaluate import parse_ids  # noqa: E402
from service.rejection import (  # noqa: E402
    MEASURES,
    REJECT_KEY,
    SCORE_KINDS,
    STATISTICS,
    Calibration,
    read_calibrations,
)  # noqa: E402
from service.settings import Settings  # noqa: E402


def write_metadata(model: Path, out: Path, calibrations: dict[str, dict]) -> None:
    """The model with its `reject_above` metadata replaced: only metadata_props changes."""
    write_model_metadata(model, out, {REJECT_KEY: json.dumps(calibrations)})


def picture(report: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    kinds = list(report["calibrations"])
    fig, axes = plt.subplots(len(kinds), 2, figsize=(11, 4.2 * len(kinds)), squeeze=False)
    for row, kind in zip(axes, kinds, strict=True):
        cal, test = report["calibrations"][kind], report["test"].get(kind, {})
        termed = next((m for m in MEASURES if m in cal), None)
        t = cal[termed]["threshold"] if termed else cal["threshold"]
        for name, colour in (("right", "tab:green"), ("wrong", "tab:orange"), ("unknown", "tab:red")):
            xs = report["val_scores"][kind][name]
            if xs:
                row[0].hist(xs, bins=30, alpha=0.5, color=colour, density=True, label=f"{name} ({len(xs)})")
        row[0].axvline(t, color="k", ls="--", label=f"threshold {t:.3g}")
        row[0].set_xlabel(
            f"best answer's {Calibration(kind, t, 0, 0, statistic=cal['statistic'], weight=cal['weight']).describe()}"
            + (f", + {cal[termed]['weight']:g} x {MEASURES[termed]}" if termed else "")
        )
        row[0].set_title(f"validation frames ({kind}): best answers' scores")
        row[0].legend(fontsize=8)
        # left one video out: each video's curve, with the threshold chosen on the others
        videos = report.get("leave_one_video_out", {})
        blocks = {f"video {v}, ": p["test"][kind] for v, p in videos.items()} or {"": test}
        for said, block in blocks.items():
            for n, by in block.get("by_registered", {}).items():
                if not by["n_unknown"] or "curve" not in by:
                    continue  # every object registered: no unknowns to reject
                c = by["curve"]
                row[1].plot(c["rejected_unknown"], c["recall"], label=f"{said}{n} registered")
                row[1].plot(by["rejected_unknown"], 1 - by["rejected_right"], "ko", ms=4)
        row[1].set_xlabel("patches of unregistered objects rejected")
        row[1].set_ylabel("right answers kept")
        title = "each video, set on the others" if videos else "test frames"
        row[1].set_title(f"{title} ({kind}); dots: the calibrated threshold")
        row[1].grid(alpha=0.3)
        row[1].legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)


#: the default rule: reject at most this share of the registered objects' validation patches. Below the
#: 10 % aimed at on new frames: the rgb threshold of "keep 0.9 of right answers" on validation rejected 13.6 %
#: of the registered objects' patches of the test frames
REJECT_REGISTERED = 0.08


def term_weights(given: list[str]) -> dict[str, float]:
    """--colour-weight or --fit-weight values: score kind -> the term's weight (0: none)."""
    out = {}
    for text in given:
        kind, _, weight = text.rpartition("=")
        try:
            w = float(weight)
        except ValueError:
            w = -1.0
        if kind not in SCORE_KINDS or w < 0:
            raise ValueError(f"{text!r}: KIND=WEIGHT, KIND 'local' or 'descriptor', WEIGHT >= 0")
        out[kind] = w
    return out


def term_asked(
    weights: dict[str, dict[str, float]], kind: str, shipped: Calibration | None
) -> tuple[str | None, float]:
    """The term a score kind is calibrated with: (measure, weight) as asked (`--colour-weight`,
    `--fit-weight`), else the shipped calibration's (recalibrated as shipped), else (None, 0)."""
    for which, by_kind in weights.items():
        if kind in by_kind:
            return which, by_kind[kind]
    for which in MEASURES:
        if shipped is not None and (term := shipped.term(which)) is not None:
            return which, term.weight
    return None, 0.0


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


def fitted(
    a: Answers,
    kind: str,
    chosen: dict[str, tuple[str, float]],
    weights: dict[str, dict[str, float]],
    shipped: dict[str, Calibration],
    rule: tuple[str, float],
) -> tuple[Calibration, dict]:
    """One score kind's calibration on `a` (its statistic as `--statistic` says, or the shipped one's) by
    `rule`, with its colour or fit term where one is asked for or shipped; and its report."""
    name, weight = chosen.get(kind, chosen.get("", ("distance", 0.0)))
    stat = Calibration(kind, 0.0, 0.0, 0.0, statistic=name, weight=weight)
    cal, rep = calibrate(a, shipped.get(kind) or stat, rule, "val")
    asked, weighed = term_asked(weights, kind, shipped.get(kind))
    if asked is not None and weighed:
        plain = rep
        cal, rep = calibrate_term(a, cal, asked, weighed, rule)
        rep["without_term"] = {"threshold": cal.threshold, "at_threshold": plain["at_threshold"]}
    return cal, rep


def as_weights(cal: Calibration) -> tuple[float | None, float]:
    """A calibration's statistic as `evaluation.videos.weights_by_video` names one: the lead's weight (None: the
    distance) and its fit term's weight (0: none)."""
    term = cal.term("fit")
    return None if cal.statistic == "distance" else cal.weight, 0.0 if term is None else term.weight


#: what `held_out` prints of each video: with the fewest objects registered (some left out)
SAID = ("rejected_unknown", "rejected_registered")


def held_out(
    args: argparse.Namespace,
    a: Answers,
    sets: list[list[int]],
    fit: Callable[[Answers, str], tuple[Calibration, dict]],
    describe: Callable[[Calibration, list[int]], dict],
) -> tuple[dict, dict]:
    """`--leave-one-video-out`: each video measured with the calibration `fit` chooses on the others (and,
    with `--held-out-models`, that calibration written into DIR/<video>/<model file>, beside copies of the
    other models of its folder: a models folder to evaluate that video with); per video, and the mean over
    them by score kind (`evaluation.videos.mean_of`)."""
    per_video: dict[int, dict] = {}
    for video in sorted(set(a.scene)):
        others = sorted(set(a.scene) - {video})
        train, test = of_videos(a, others), of_videos(a, [video])
        cals = {kind: fit(train, kind)[0] for kind in a.kinds}
        per_video[video] = {
            "calibrated_on": others,
            "thresholds": {k: decision_threshold(c) for k, c in cals.items()},
            "test": {k: measure(test, c, sets, args.fold) for k, c in cals.items()},
        }
        if args.held_out_models is not None:
            out = args.held_out_models / f"{video:06d}" / args.model.name
            out.parent.mkdir(parents=True, exist_ok=True)
            write_metadata(args.model, out, {k: describe(c, others) for k, c in cals.items()})
            # a models folder: the model's neighbours copied as they are
            for beside in args.model.parent.glob("posedesc-*.onnx"):
                if beside.name != args.model.name:
                    shutil.copyfile(beside, out.parent / beside.name)
        print(f"video {video:06d}, calibrated on {others}: " + json.dumps({
            k: {x: b["by_registered"][min(b["by_registered"], key=int)].get(x) for x in SAID}
            for k, b in per_video[video]["test"].items()}))  # fmt: skip
    mean = {k: mean_of({v: p["test"][k] for v, p in per_video.items()}) for k in a.kinds}
    return {str(v): p for v, p in per_video.items()}, mean


def frames_of(args: argparse.Namespace, meta: dict[str, str]) -> tuple[list[int] | None, list[int] | None]:
    """(validation, test) frames: with `--video-split`, every frame (None) of the validation video and of
    the others; else the model's `split_frames`, or those of `--splits-from` (a model trained with the same
    data) kept within `--held-out` (the frames this model was not trained on)."""
    if args.video_split is not None:
        return None, None
    if args.splits_from is not None:
        meta = Embedder(args.splits_from).info.extra
    val = split_frames(meta, args.dataset, args.scene, "val") or []
    test = split_frames(meta, args.dataset, args.scene, "test") or []
    if args.held_out:
        kept = set(parse_ids(args.held_out))
        val, test = [f for f in val if f in kept], [f for f in test if f in kept]
    return val, test


def scenes_of(args: argparse.Namespace, split: str) -> list[int]:
    """The split's scenes: with `--video-split V` (a scene, or several: `0,1`), V for validation and the
    dataset's other scenes for test (consecutive frames of a video are near-duplicates: a video is in one
    split only; none left: no test); else `--scene`."""
    if args.video_split is None:
        return [args.scene]
    chosen = [int(x) for x in str(args.video_split).split(",") if x.strip()]
    scenes = [int(d.name) for d in BopDataset(args.dataset).scene_dirs() if d.name.isdigit()]
    if missing := sorted(set(chosen) - set(scenes)):
        sys.exit(f"error: --video-split: no scene {missing[0]} in {args.dataset}")
    return chosen if split == "val" else [s for s in scenes if s not in chosen]


def answers(args: argparse.Namespace, split: str, frames: list[int] | None, sets: list[list[int]]) -> Answers:
    """The split's answers: read from `--cache` when they were collected by the same network (its graph's
    digest: another network of the same file name, a retrained model, collects its own; a calibration
    written into the file keeps them) with the same frames, sets, settings and code (`code_digest`), else collected
    (`evaluation.openset.collect`) and written there."""
    scenes = scenes_of(args, split)
    path = args.cache / f"{args.model.stem}-{args.dataset.resolve().name}-{split}.json"
    network = graph_digest(onnx.load(args.model))
    key = {"network": network, "scenes": scenes, "frames": frames, "sets": sets,
           "settings": Settings().model_dump(mode="json"), "code": code_digest()}  # fmt: skip
    if path.is_file():
        cached = json.loads(path.read_text())
        if cached.get("key") == key:
            return Answers(**cached["answers"])
    a = collect(args.model, args.dataset, frames, sets, scenes, seed=args.seed)
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
    ap.add_argument(
        "--choose-weights",
        action="store_true",
        help="with --leave-one-video-out: also choose the lead's and the fit term's weights on the other videos",
    )
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
    ap.add_argument("--video-split", default=None, metavar="SCENES",
                    help="validate on these scenes (videos, e.g. 0 or 0,1), test on the dataset's others; "
                    "not --scene")  # fmt: skip
    ap.add_argument("--leave-one-video-out", action="store_true",
                    help="every video (scene) measured with the calibration chosen on the others (the JSON's "
                    "test: the mean over the videos); the one written (--out) is chosen on them all")  # fmt: skip
    ap.add_argument("--held-out-models", type=Path, default=None, metavar="DIR",
                    help="with --leave-one-video-out: DIR/<video>/, the model calibrated without that video beside "
                    "the other models of its folder")  # fmt: skip
    ap.add_argument("--fold", type=int, default=1, help="objects left out at once (each object once)")
    ap.add_argument("--shipped", action="store_true",
                    help="fit nothing: measure the model's own calibration on both splits")  # fmt: skip
    ap.add_argument(
        "--colour-weight",
        action="append",
        default=[],
        metavar="KIND=WEIGHT",
        help="a colour term for that score kind (service.rejection.Term): the best answer's "
        "statistic plus WEIGHT x its colour distance where a colour frame shows it (0: none; "
        "default: the shipped calibration's)",
    )
    ap.add_argument(
        "--fit-weight",
        action="append",
        default=[],
        metavar="KIND=WEIGHT",
        help="instead, a fit term: the best answer's statistic plus WEIGHT x the share of it the depth "
        "leaves unexplained where a frame with depth shows it (0: none; default: the shipped calibration's)",
    )
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
    weights: dict[str, dict[str, float]] = {}
    for which, given in (("colour", args.colour_weight), ("fit", args.fit_weight)):
        try:
            weights[which] = term_weights(given)
        except ValueError as e:
            sys.exit(f"--{which}-weight: {e}")
    if both := sorted(k for k, w in weights["colour"].items() if w and weights["fit"].get(k)):
        sys.exit(f"--colour-weight and --fit-weight: one term a score kind ({both[0]} has both)")
    if not 0 <= args.reject_registered < 1:
        sys.exit("--reject-registered: a share in [0, 1)")
    if args.leave_one_video_out:
        if args.video_split is not None or args.shipped:
            sys.exit(
                "--leave-one-video-out chooses the videos itself and fits: not with --video-split or --shipped"
            )
        scenes = [d.name for d in BopDataset(args.dataset).scene_dirs() if d.name.isdigit()]
        if len(scenes) < 2:
            sys.exit(
                f"--leave-one-video-out: {args.dataset} has {len(scenes)} video(s); it needs two or more"
            )
        args.video_split = ",".join(str(int(x)) for x in scenes)  # every video validates; each in turn tests
    elif args.held_out_models is not None:
        sys.exit("--held-out-models: only with --leave-one-video-out")
    elif args.choose_weights:
        sys.exit("--choose-weights: only with --leave-one-video-out")
    if args.shipped and args.out is not None:
        sys.exit("--shipped measures the model's own calibration: it writes no model (--out)")
    if args.out is not None and not args.out.parent.is_dir():
        sys.exit(f"--out: no folder {args.out.parent}")
    if not 1 <= args.fold < len(BopDataset(args.dataset).obj_ids):
        sys.exit("--fold: at least 1, fewer than the dataset's objects")
    embedder = Embedder(args.model)
    shipped = read_calibrations(embedder.info.extra, args.model.name)
    if args.shipped and not shipped:
        sys.exit(f"{args.model} has no calibration to measure")
    val, test = frames_of(args, embedder.info.extra)
    if val == []:
        sys.exit(f"{args.model} names no val frames of {args.dataset.name} scene {args.scene} (split_frames)")
    objects = BopDataset(args.dataset).obj_ids
    sizes = [int(x) for x in args.sizes.split(",") if x.strip()]
    val_sets = registered_sets(objects, [], 0, args.seed, args.fold)
    test_sets = registered_sets(objects, sizes, args.per_size, args.seed, args.fold)
    a = answers(args, "val", val, val_sets)
    tested = test != [] and not args.no_test and (args.video_split is None or scenes_of(args, "test"))
    t = answers(args, "test", test, test_sets) if tested else None
    if args.collect_only:
        return
    rule = ("right", args.keep_right) if args.keep_right else ("registered", args.reject_registered)
    stem = args.model.stem + (f"-{args.dataset.resolve().name}" if args.video_split is not None else "")
    stem += "-shipped" if args.shipped else ""

    def chosen_on(scenes: list[int]) -> str:
        return f"{args.dataset.resolve().name}/" + "+".join(f"{s:06d}" for s in scenes)

    dataset = chosen_on(scenes_of(args, "val"))
    report: dict = {
        "model": str(args.model), "dataset": dataset, "objects": objects, "data": a.data,
        "command": " ".join(["scripts/calibrate_reject.py", *sys.argv[1:]]),
        "frames": {"val": val, "test": test},
        "scenes": {"val": scenes_of(args, "val"), "test": scenes_of(args, "test")}, "fold": args.fold,
        "rule": "the model's own (--shipped)" if args.shipped else
        f"keep {rule[1]} of right answers" if rule[0] == "right" else
        f"reject at most {rule[1]} of the registered objects' validation patches",
        "calibrations": {}, "explored": {}, "compare_filtered": {}, "val_scores": {}, "test": {},
    }  # fmt: skip

    def described(cal: Calibration, scenes: list[int]) -> dict:
        """A calibration as the model's metadata keeps it: with what it was chosen on, and by which rule."""
        on = chosen_on(scenes)
        return {
            **cal.to_json(),
            "dataset": on,
            "objects": len(objects),
            "rule": report["rule"],
            "data": a.data,
        }

    metadata = {}
    for kind in a.kinds:
        cal, rep = fitted(a, kind, chosen, weights, shipped, rule)
        if args.shipped:  # nothing fitted: the validation frames are measured like the test frames
            cal = shipped[kind]
            rep["at_threshold"] = measure(a, cal, val_sets, args.fold)["by_registered"]
        if not args.shipped:
            cal = replace(cal, graph=embedder.graph_digest)
        metadata[kind] = described(cal, scenes_of(args, "val"))
        report["calibrations"][kind] = {**metadata[kind], **rep}
        report["explored"][kind] = explore(a, kind)
        report["compare_filtered"][kind] = compare_filtered(a, kind, cal)
        report["val_scores"][kind] = {k: np.round(v, 4).tolist() for k, v in zip(
            ("right", "wrong", "unknown"), kinds_of(a, kind, cal), strict=True)}  # fmt: skip
        print(
            f"{kind}: {cal.describe(term_of(cal))} threshold {decision_threshold(cal):.4g}, val {rep['at_threshold']}"
        )
        for row in report["explored"][kind]:
            print(f"  explored {kind}: {json.dumps(row)}")
        print(f"  one collection filtered against left-out runs: {report['compare_filtered'][kind]}")
        if t is not None:
            report["test"][kind] = measure(t, cal, test_sets, args.fold)
            for o, by in report["test"][kind]["per_unregistered_object"].items():
                print(f"{kind} test, object {o} unregistered: {json.dumps(by)}")
    if args.leave_one_video_out:

        def fit(x: Answers, kind: str) -> tuple[Calibration, dict]:
            return fitted(x, kind, chosen, weights, shipped, rule)

        def describe(cal: Calibration, videos: list[int]) -> dict:
            return described(replace(cal, graph=embedder.graph_digest), videos)

        report["leave_one_video_out"], report["test"] = held_out(args, a, val_sets, fit, describe)
        if args.choose_weights:  # the statistic's weights chosen per video too (docs/experiments.md)
            report["weights_left_out"] = {
                k: weights_by_video(a, k, rule, val_sets, args.fold, as_weights(fit(a, k)[0]))
                for k in a.kinds
            }
            print(json.dumps({k: w["mean"] for k, w in report["weights_left_out"].items()}))
        test_sets = val_sets
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
