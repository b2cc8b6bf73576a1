"""Train, export and measure the whole-frame objectness network (training/objectness/).

    scripts/train_objectness.py train --data /work/shared/data/lmo --out /work/runs/objectness --minutes 35
    scripts/train_objectness.py export --run /work/runs/objectness --out models/posedesc-objectness.onnx
    scripts/train_objectness.py measure --model models/posedesc-objectness.onnx --split val \
        --json docs/results/objectness-val.json

`measure` runs the exported ONNX model through `index.features.objectness.propose` (no torch) on the frames of one
split and writes recall at the top 5/10/20/30 proposals and the median time of one `propose` call on a
640 x 480 frame (one thread)."""

from __future__ import annotations

import argparse
import json
import logging
import os
import shlex
import sys
import time
from dataclasses import fields
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")


def _commit() -> str:
    from posedesc.commands.train import _code_version  # the one reading of the code's commit

    return _code_version() or "unknown"


def _train(args: argparse.Namespace) -> int:
    from training.objectness import ObjectnessConfig, train

    cfg = ObjectnessConfig(
        minutes=args.minutes,
        seed=args.seed,
        batch=args.batch,
        val_every=args.val_every,
        lr=args.lr,
        background=args.background,
        scrambled=args.scrambled,
        holdout=tuple(int(x) for x in args.holdout.split(",") if x),
        objects=args.objects,
        shapes=args.shapes,
        shape_views=args.shape_views,
        real_objects=args.real_objects,
        negative_paste=args.negative_paste,
        photo_share=args.photo_share,
        harmonise=args.harmonise,
        select_by=args.select_by,
        paste=tuple(int(x) for x in args.paste.split(",")),  # type: ignore[arg-type]  # two ints
    )
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "command.txt").write_text(
        json.dumps({"command": shlex.join(["scripts/train_objectness.py", *sys.argv[1:]]), "code": _commit()})
    )
    state = train(args.data, args.out, cfg, args.cache, threads=args.threads, init=args.init)
    print(json.dumps({"best_step": state["step"], "val": state["val"]}, indent=1))
    return 0


def _export(args: argparse.Namespace) -> int:
    from training.objectness import export, load_checkpoint

    net, cfg, state = load_checkpoint(args.run / args.checkpoint)
    run = json.loads((args.run / "command.txt").read_text()) if (args.run / "command.txt").is_file() else {}
    extra = {
        "command": run.get("command", "unknown"),
        "code": run.get("code", "unknown"),
        "step": str(state["step"]),
        "checkpoint": "best on validation frames (recall of lmo/000002 val frames, top 20)",
        "validation_in_training": json.dumps(state["val"]),  # its 5 levels, before suppression fused
        "split_frames": "training/splits.py defaults on lmo/000002: trained on train frames only",
    }
    if args.val_json:  # the figures `measure` wrote for the exported model, on the validation frames
        figures = json.loads(args.val_json.read_text())
        extra["val_figures"] = json.dumps(
            {k: figures[k] for k in ("recall_by_window", "propose_ms_640x480_median")}
        )
    levels = tuple(float(x) for x in args.levels.split(",")) if args.levels else None
    path = export(net, cfg, args.out, extra, levels)
    print(f"{path}: {path.stat().st_size / 1e6:.2f} MB")
    return 0


def _measure(args: argparse.Namespace) -> int:
    from index.features.objectness import ObjectnessNet, propose
    from training.objectness import load_frames
    from training.objectness.recall import recall

    net = ObjectnessNet(args.model, threads=1)
    frames = load_frames(args.data, args.split)
    levels = tuple(float(x) for x in args.levels.split(",")) if args.levels else net.levels
    found = [propose(net, f.rgb, limit=30, levels=levels) for f in frames]
    pairs = [(p, f.truths(0.5)) for p, f in zip(found, frames, strict=True)]
    ids = sorted({int(i) for f in frames for i in f.ids})
    per_object = {  # each object's recall alone: a held-out object's against the others'
        str(i): recall([(p, f.truths(0.5, only={i})) for p, f in zip(found, frames, strict=True)])["w/8, 12%"]
        | {"n": sum(len(f.truths(0.5, only={i})) for f in frames)}
        for i in ids
    }
    frame = frames[0].rgb
    propose(net, frame, levels=levels)
    times = []
    for _ in range(args.repeats):
        t = time.perf_counter()
        propose(net, frame, levels=levels)
        times.append(time.perf_counter() - t)
    result = {
        "split": args.split,
        "frames": len(frames),
        "instances": sum(len(t) for _, t in pairs),
        "min_visib": 0.5,
        "levels": list(levels),
        "recall_by_window": recall(pairs),
        "recall_by_extent_and_true_diameter": recall(pairs, by_extent=True),
        "per_object_w8_12": per_object,
        "held_out": json.loads(net.metadata.get("config", "{}")).get("holdout", []),
        "propose_ms_640x480_median": round(1000 * float(np.median(times)), 1),
        "threads": 1,
        "repeats": args.repeats,
        "model": str(args.model),
        "model_step": net.metadata.get("step"),
        "command": shlex.join(["scripts/train_objectness.py", *sys.argv[1:]]),
        "code": _commit(),
    }
    text = json.dumps(result, indent=1)
    print(text)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text + "\n")
    return 0


def main(argv: list[str] | None = None) -> int:
    from training.objectness import ObjectnessConfig

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train")
    t.add_argument("--data", type=Path, default=Path("/work/shared/data/lmo"))
    t.add_argument("--out", type=Path, required=True)
    t.add_argument("--cache", type=Path, default=Path("/work/runs/objectness-cache"))
    t.add_argument("--minutes", type=float, default=35.0)
    t.add_argument("--threads", type=int, default=2)
    t.add_argument("--seed", type=int, default=0)
    names = {f.name: f.default for f in fields(ObjectnessConfig)}
    t.add_argument("--batch", type=int, default=names["batch"])
    t.add_argument("--val-every", type=int, default=names["val_every"])
    t.add_argument("--lr", type=float, default=names["lr"])
    t.add_argument("--background", choices=("negative", "ignore"), default=names["background"])
    t.add_argument("--scrambled", type=float, default=names["scrambled"])
    t.add_argument("--holdout", default="", help="object ids treated as never seen, comma-separated")
    t.add_argument(
        "--objects",
        choices=("shapes", "catalogue"),
        default=names["objects"],
        help="what is pasted: procedural shapes, or pybullet's random_urdfs then shapes",
    )
    t.add_argument("--shapes", type=int, default=names["shapes"], help="objects rendered for pasting")
    t.add_argument("--shape-views", type=int, default=names["shape_views"], help="renders of each")
    t.add_argument(
        "--real-objects",
        choices=("target", "held"),
        default=names["real_objects"],
        help="held: the frames' annotated objects are never learned (neither target nor background)",
    )
    t.add_argument("--negative-paste", type=float, default=names["negative_paste"])
    t.add_argument("--photo-share", type=float, default=names["photo_share"])
    t.add_argument("--harmonise", type=float, default=names["harmonise"])
    t.add_argument("--select-by", choices=("window", "extent"), default=names["select_by"])
    t.add_argument("--paste", default=",".join(map(str, names["paste"])), help="pastes a crop: min,max")
    t.add_argument("--init", type=Path, help="a checkpoint (best.pt) whose head this run goes on training")
    e = sub.add_parser("export")
    e.add_argument("--run", type=Path, required=True)
    e.add_argument("--checkpoint", default="best.pt")
    e.add_argument("--out", type=Path, default=Path("models/posedesc-objectness.onnx"))
    e.add_argument(
        "--levels", help="pyramid scales propose runs by default, comma-separated (default: trained)"
    )
    e.add_argument(
        "--val-json", type=Path, help="measure's JSON of the validation frames, kept in the metadata"
    )
    m = sub.add_parser("measure")
    m.add_argument("--model", type=Path, default=Path("models/posedesc-objectness.onnx"))
    m.add_argument("--data", type=Path, default=Path("/work/shared/data/lmo"))
    m.add_argument("--split", choices=("val", "test"), default="val")
    m.add_argument("--json", type=Path)
    m.add_argument("--repeats", type=int, default=20)
    m.add_argument("--levels", help="pyramid scales, comma-separated (default: the model's)")
    args = p.parse_args(argv)
    for path in [getattr(args, k) for k in ("data", "model", "run") if getattr(args, k, None) is not None]:
        if not path.exists():
            p.error(f"{path} does not exist")
    return {"train": _train, "export": _export, "measure": _measure}[args.cmd](args)


if __name__ == "__main__":
    sys.exit(main())
