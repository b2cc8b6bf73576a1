"""Measure recognition and pose accuracy as the paper does, beside HOG and LineMOD: JSON and a report."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

from posedesc.cli import UserError

METHODS = ("ours", "hog", "linemod")


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


def heldout_frames(meta: dict[str, str], dataset: Path, scene: int) -> list[int] | None:
    """The frames of `dataset`'s scene a model was not trained on, from its `heldout_frames` metadata
    ({"<dataset folder>/<scene>": [frame ids]}, written by `posedesc export`); None when it has none."""
    try:
        heldout = json.loads(meta.get("heldout_frames", "{}"))
    except json.JSONDecodeError:
        return None
    frames = heldout.get(f"{dataset.resolve().name}/{scene:06d}")
    return sorted(int(f) for f in frames) if frames else None


def _frames(args: argparse.Namespace, embedder) -> list[int] | None:
    if not args.frames:
        return None
    if args.frames.strip() == "heldout":
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
    p.add_argument("--protocol", choices=("paper", "full"), default="paper",
                   help="paper: rectified patch, viewing-direction error; full: in-plane estimated, "
                   "3-D rotation error")  # fmt: skip
    p.add_argument("--methods", default=",".join(METHODS), help="comma-separated: ours,hog,linemod")
    p.add_argument("--unseen", default="", help="ids of objects the model never saw (reported apart)")
    p.add_argument("--frames", default=None,
                   help="frames to use, e.g. 0-399,1000, or 'heldout': those the model's metadata says "
                   "training never saw (default: all)")  # fmt: skip
    p.add_argument("--objects", default=None, help="register only these object ids (default: all)")
    p.add_argument("--inplane-step", type=float, default=20.0, help="full protocol: in-plane step, deg")
    p.add_argument("--synthetic", action="store_true",
                   help="synthetic test scenes even where the dataset has the images")  # fmt: skip
    p.add_argument("--model-3d", type=Path, default=None, help="a 3-dimensional model for the 3-D picture")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path, required=True, help="where to write the results")
    p.add_argument("--report", type=Path, default=None, help="folder for report.md and the pictures")


def run(args: argparse.Namespace) -> int:
    from evaluation.report import table, write_json, write_report
    from evaluation.run import Config, evaluate
    from index.embed import Embedder

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
    if args.inplane_step <= 0 or args.inplane_step > 180:
        raise UserError("--inplane-step must be in (0, 180]")
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
        synthetic=True if args.synthetic else None,
        seed=args.seed,
    )
    t0 = time.perf_counter()
    ev = evaluate(cfg, embedder)
    summary = write_json(ev, args.json)
    command = "posedesc evaluate " + shlex.join(sys.argv[2:] if sys.argv[1:2] == ["evaluate"] else [])
    if args.report:
        write_report(ev, args.report, command.strip(), args.model_3d)
    print(table(summary))
    where = f"{args.json}" + (f" and {args.report}/report.md" if args.report else "")
    print(
        f"{summary['n_samples']} {summary['test_data']} test patches, {summary['n_templates']} templates, "
        f"{time.perf_counter() - t0:.0f} s -> {where}"
    )
    return 0
