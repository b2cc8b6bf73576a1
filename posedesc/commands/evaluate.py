"""Measure accuracy as the API answers, beside HOG and LineMOD.

What POST /recognize answers (or the paper's protocols) on a BOP dataset's frames, beside HOG and
LineMOD on the same patches and templates: JSON, and a report with pictures.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

from evaluation.splits import heldout_frames, split_frames
from posedesc.cli import UserError

METHODS = ("ours", "hog", "linemod")
PROTOCOLS = ("service", "paper", "full", "detect")
SPLITS = ("train", "val", "test")


def parse_ids(text: str) -> list[int]:
    """ "3,8,100-120" -> [3, 8, 100, ..., 120] (ranges inclusive)."""
    out: list[int] = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        lo, sep, hi = part.partition("-")
        try:
            out += list(range(int(lo), int(hi) + 1)) if sep else [int(part)]
        except ValueError:
            raise UserError(f"not a list of numbers and ranges: {text!r} (e.g. 3,8,100-120)") from None
    return sorted(set(out))


def _frames(args: argparse.Namespace, embedder) -> list[int] | None:
    if not args.frames:
        return None
    name = args.frames.strip()
    if name in SPLITS:
        frames = split_frames(embedder.info.extra, args.dataset, args.scene, name)
        if not frames:
            raise UserError(
                f"{args.model} names no {name} frames of {args.dataset.name} scene {args.scene} "
                "(no split_frames in its metadata)"
            )
        return frames
    if name == "heldout":
        frames = heldout_frames(embedder.info.extra, args.dataset, args.scene)
        if not frames:
            raise UserError(
                f"{args.model} names no held-out frames of {args.dataset.name} scene {args.scene}"
            )
        return frames
    return parse_ids(args.frames)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dataset", type=Path, required=True, help="BOP dataset folder (models/, test/)")
    p.add_argument("--modality", choices=("rgb", "depth", "rgbd"), required=True)
    p.add_argument("--model", type=Path, required=True, help="ONNX descriptor model of that modality")
    p.add_argument("--scene", type=int, default=2, help="test scene id")
    p.add_argument("--min-visib", type=float, default=0.5, help="least visible fraction of an instance")
    p.add_argument("--protocol", choices=PROTOCOLS, default="service",
                   help="service: what POST /recognize answers, called in process with the "
                   "frame, camera, centre and distance (colour) or depth, as a user sends them; templates "
                   "from the service's registration and settings; 3-D rotation error (in-plane included) "
                   "and viewing-direction error of the top answers, the open set on (a query answered 'no "
                   "known object', by POSEDESC_REJECT_ABOVE or the model's calibration, is a miss; the "
                   "figures with it off beside them). paper: patch cut at the true centre and rectified by "
                   "the true in-plane angle, viewing-direction error. full: true centre and distance, "
                   "templates with in-plane variants over the whole turn, 3-D rotation error. detect: every "
                   "frame sent whole with its intrinsics only to the service's detector; recall, precision, "
                   "AP50, poses within 20 deg, distance errors, per object (evaluation/detect/run.py)")  # fmt: skip
    p.add_argument("--methods", default=",".join(METHODS), help="comma-separated: ours,hog,linemod")
    p.add_argument("--unseen", default="", help="ids of objects the model never saw (reported apart)")
    p.add_argument("--frames", default=None,
                   help="frames to use (ids): a list like 0-39,50; 'val' or 'test': the model's split "
                   "(its split_frames metadata); 'heldout': those its heldout_frames metadata says "
                   "training never saw (default: all)")  # fmt: skip
    p.add_argument("--objects", default=None, help="register only these object ids (default: all)")
    p.add_argument("--distractors", type=Path, default=None,
                   help="service protocol: register every object of this BOP dataset too, never asked about "
                   "(an answer naming one is wrong), e.g. shape-only meshes beside textured ones")  # fmt: skip
    p.add_argument("--inplane-step", type=float, default=None,
                   help="full protocol: in-plane step of the templates, degrees (default 20); service "
                   "protocol: the service's INPLANE_STEP setting (default: POSEDESC_INPLANE_STEP, else "
                   "the model's metadata)")  # fmt: skip
    p.add_argument(
        "--inplane-max",
        type=float,
        default=None,
        help="service protocol: the service's INPLANE_MAX setting (>= 180: the whole turn)",
    )
    p.add_argument("--query-turns", type=int, default=None,
                   help="service protocol: the service's QUERY_TURNS setting (default: "
                   "POSEDESC_QUERY_TURNS, else 1)")  # fmt: skip
    p.add_argument("--synthetic", action="store_true",
                   help="synthetic test scenes (colour too) even where the dataset has the images; "
                   "without it, depth and rgbd on colour frames without depth (LM-O) get the real colour "
                   "with depth rendered from the ground truth (service protocol)")  # fmt: skip
    p.add_argument(
        "--oracle-mask",
        action="store_true",
        help="service protocol: send each frame black outside the instance's true visible mask "
        "(the clutter-free bound; colour only)",
    )
    p.add_argument(
        "--patches",
        action="store_true",
        help="service protocol: send each instance as the patch a user would cut from its frame through its "
        "object's registered window, with that window and the distance, no camera (--methods ours)",
    )
    p.add_argument("--rolls", default=None,
                   help="service protocol: send every frame again turned about the principal point by "
                   "each of these camera rolls, degrees, e.g. 0,72,144,216,288, the poses turned with it "
                   "(a larger validation yardstick from the same frames)")  # fmt: skip
    p.add_argument("--model-3d", type=Path, default=None, help="a 3-dimensional model for the 3-D picture")
    p.add_argument(
        "--seed", type=int, default=0, help="seed of synthetic scenes and of the pictures' samples"
    )
    p.add_argument("--max-detections", type=int, default=None,
                   help="detect protocol: detections reported per frame (default 10)")  # fmt: skip
    p.add_argument("--min-confidence", type=float, default=None,
                   help="detect protocol: the confidence a detection needs (default: the model's open-set "
                   "verdict decides)")  # fmt: skip
    p.add_argument("--linemod", action="store_true",
                   help="detect protocol: OpenCV's LineMOD over a frame pyramid beside it")  # fmt: skip
    p.add_argument("--false-alarms", action="store_true",
                   help="detect protocol: also the same frames with only objects not in them registered "
                   "(the demo shapes and generated shapes): detections per frame")  # fmt: skip
    p.add_argument("--json", "--out", type=Path, required=True,
                   help="where to write the results (the service and detect protocols add a 'bop' block: "
                   "MSSD, MSPD, ADD(-S), te, re of each target's estimate; AR_MSSD, AR_MSPD, AR, ADD(-S) "
                   "and 5 deg 5 cm recalls)")  # fmt: skip
    p.add_argument("--bop-csv", type=Path, default=None,
                   help="also write BOP19 results rows (scene_id,im_id,obj_id,score,R,t,time): service "
                   "protocol, the best answer of each query not rejected; detect protocol, every detection "
                   "reported")  # fmt: skip
    p.add_argument("--report", type=Path, default=None, help="folder for report.md and the pictures")


def run(args: argparse.Namespace) -> int:
    from pydantic import ValidationError

    from evaluation.bop.csv import write_bop_csv
    from evaluation.config import Config
    from evaluation.report import tables_text, write_json, write_report
    from evaluation.rolls import parse_rolls
    from evaluation.run import evaluate
    from index.features.embed import Embedder

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    if not methods or set(methods) - set(METHODS):
        raise UserError(f"--methods: choose from {','.join(METHODS)}, got {args.methods!r}")
    if not args.model.is_file():
        raise UserError(f"no such model: {args.model}")
    for path in (args.model_3d,):
        if path is not None and not path.is_file():
            raise UserError(f"no such model: {path}")
    embedder = Embedder(args.model, threads=2)
    if embedder.modality != args.modality:
        raise UserError(f"{args.model} is a {embedder.modality} model, not {args.modality}")
    detect_only = {"--max-detections": args.max_detections is not None,
                   "--min-confidence": args.min_confidence is not None,
                   "--linemod": args.linemod, "--false-alarms": args.false_alarms}  # fmt: skip
    if args.protocol == "detect":
        return _detect(args, embedder)
    if given := [k for k, v in detect_only.items() if v]:
        raise UserError(f"{', '.join(given)}: only with --protocol detect")
    if args.inplane_step is not None and not (0 <= args.inplane_step <= 180):
        raise UserError("--inplane-step must be in [0, 180]")
    if args.protocol == "full" and args.inplane_step == 0:
        raise UserError("--inplane-step must be in (0, 180] for the full protocol")
    if args.oracle_mask and (args.protocol != "service" or args.modality == "depth"):
        raise UserError("--oracle-mask needs the service protocol and colour (rgb or rgbd)")
    if args.patches and (
        args.protocol != "service" or methods != ("ours",) or args.rolls or args.oracle_mask
    ):
        raise UserError(
            "--patches needs the service protocol and --methods ours, without --rolls or --oracle-mask"
        )
    rolls: tuple[float, ...] = ()
    if args.rolls is not None:
        if args.protocol != "service":
            raise UserError("--rolls needs the service protocol")
        try:
            rolls = parse_rolls(args.rolls)
        except ValueError as e:
            raise UserError(f"--rolls: {e}") from None
    if args.bop_csv is not None and (args.protocol != "service" or rolls):
        raise UserError(
            "--bop-csv needs the service protocol, without --rolls (a frame sent at several rolls)"
        )
    if args.query_turns is not None and not (1 <= args.query_turns <= 36):
        raise UserError("--query-turns must be in 1..36")
    if args.distractors is not None:
        if args.protocol != "service":
            raise UserError("--distractors needs the service protocol")
        if not (args.distractors / "models" / "models_info.json").is_file():
            raise UserError(
                f"--distractors: {args.distractors} is not a BOP dataset (no models/models_info.json)"
            )
    cfg = Config(
        dataset=args.dataset,
        model=args.model,
        modality=args.modality,
        scene=args.scene,
        min_visib=args.min_visib,
        protocol=args.protocol,
        methods=methods,
        unseen=tuple(parse_ids(args.unseen)),
        frames=_frames(args, embedder),
        objects=parse_ids(args.objects) if args.objects else None,
        inplane_step=args.inplane_step,
        inplane_max=args.inplane_max,
        query_turns=args.query_turns,
        synthetic=True if args.synthetic else None,
        oracle_mask=args.oracle_mask,
        rolls=rolls,
        distractors=args.distractors,
        patches=args.patches,
        seed=args.seed,
    )
    t0 = time.perf_counter()
    try:
        ev = evaluate(cfg, embedder)
    except ValidationError as e:  # a service setting out of range (POSEDESC_* or an option)
        raise bad_setting(e) from None
    summary = write_json(ev, args.json)
    if args.bop_csv is not None:
        args.bop_csv.parent.mkdir(parents=True, exist_ok=True)
        n = write_bop_csv(args.bop_csv, ev.bop_estimates)
        print(f"{n} BOP19 rows (the best answer of each query not rejected) -> {args.bop_csv}")
    command = "posedesc evaluate " + shlex.join(sys.argv[2:] if sys.argv[1:2] == ["evaluate"] else [])
    if args.report:
        write_report(ev, args.report, command.strip(), args.model_3d)
    print(tables_text(summary))
    where = f"{args.json}" + (f" and {args.report}/report.md" if args.report else "")
    timing = summary.get("timing_ms")
    calls = f", recognise median {timing['recognise_median']} ms" if timing else ""
    print(
        f"{summary['n_samples']} {summary['test_data']} test patches, {summary['n_templates']} templates, "
        f"{time.perf_counter() - t0:.0f} s{calls} -> {where}"
    )
    return 0


def bad_setting(e) -> UserError:
    """A pydantic ValidationError of the service's settings as one line."""
    return UserError("bad setting: " + "; ".join(f"{x['loc'][0]}: {x['msg']}" for x in e.errors()))


def _detect(args: argparse.Namespace, embedder) -> int:
    """`--protocol detect`: the JSON and a table (`evaluation.detect.run`)."""
    from pydantic import ValidationError

    from evaluation.bop.csv import write_bop_csv
    from evaluation.detect.run import DetectConfig, evaluate_detect, table
    from evaluation.report import bop_text

    if args.max_detections is not None and not (1 <= args.max_detections <= 100):
        raise UserError("--max-detections must be in 1..100")
    if args.min_confidence is not None and not (0.0 <= args.min_confidence <= 1.0):
        raise UserError("--min-confidence must be in [0, 1]")
    ignored = [f"--{k.replace('_', '-')}" for k in ("methods", "unseen", "rolls", "report")
               if getattr(args, k) not in (None, "", ",".join(METHODS))]  # fmt: skip
    if args.min_visib != 0.5:
        raise UserError("--min-visib: the detect protocol's targets are the instances at least 0.5 visible")
    ignored += (
        ["--oracle-mask"] * args.oracle_mask + ["--synthetic"] * args.synthetic + ["--patches"] * args.patches
    )
    if ignored:
        raise UserError(f"{', '.join(ignored)}: not with --protocol detect")
    cfg = DetectConfig(
        dataset=args.dataset,
        model=args.model,
        scene=args.scene,
        frames=_frames(args, embedder),
        objects=parse_ids(args.objects) if args.objects else None,
        max_detections=args.max_detections or 10,
        min_confidence=args.min_confidence,
        linemod=args.linemod,
        false_alarms=args.false_alarms,
        seed=args.seed,
    )
    t0 = time.perf_counter()
    try:
        summary, rows = evaluate_detect(cfg)
    except ValidationError as e:  # a service setting out of range (POSEDESC_*)
        raise bad_setting(e) from None
    except ValueError as e:  # no frames, or a scene without scene_gt_info.json
        raise UserError(str(e).splitlines()[0]) from None
    summary["command"] = "posedesc evaluate " + shlex.join(
        sys.argv[2:] if sys.argv[1:2] == ["evaluate"] else []
    )
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(summary, indent=1))
    if args.bop_csv is not None:
        args.bop_csv.parent.mkdir(parents=True, exist_ok=True)
        n = write_bop_csv(args.bop_csv, rows)
        print(f"{n} BOP19 rows (every detection reported) -> {args.bop_csv}")
    print(table(summary))
    print(bop_text(summary))
    print(f"{len(summary['frames'])} frames, {time.perf_counter() - t0:.0f} s -> {args.json}")
    return 0
