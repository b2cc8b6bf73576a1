"""Measure speed beside HOG, LineMOD and exact k-NN.

Every figure beside its baseline in the same run: a table, and JSON for the README.

The default run: descriptor, recognition (8 and 100 objects), knn, http, register, roll (the shipped
model), train, guards (the times of the service's refusals) and detect (LM-O frames searched whole at 8
objects): 7.5 minutes on this project's 2-core machine before detect (measured at load 1-1.6; the roll
section is 4.8 of them), detect ~2 more. --all adds recognition at 1,000 objects, the roll section's
untrained stand-in model, detection at 100 objects, the milvus section (a Milvus server, replica
propagation), the memory section (resident memory at 100 and 1,000 objects, ~11 minutes alone) and
the fit section (the pose fit on and off on LM-O's validation frames and the Kinect frame, 35 s; `--only
fit`): 35-45 minutes. --quick: every section at tiny sizes, a few minutes (the tests').
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

from posedesc.cli import UserError

if TYPE_CHECKING:
    from benchmarks.suite import BenchConfig


def _ints(text: str) -> tuple[int, ...]:
    try:
        out = tuple(int(float(x)) for x in text.split(",") if x.strip())
    except ValueError:
        raise UserError(f"not a list of numbers: {text!r} (e.g. 8,100,1000)") from None
    if not out or min(out) <= 0:
        raise UserError(f"not a list of positive numbers: {text!r}")
    return out


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", type=Path, required=True, help="where to write the results")
    p.add_argument("--quick", action="store_true", help="every section at tiny sizes (seconds; for tests)")
    p.add_argument(
        "--only",
        default=None,
        help="comma-separated sections: descriptor,recognition,knn,http,register,roll,train,guards,detect,"
        "milvus,memory,fit (default: all but milvus, memory and fit)",
    )
    p.add_argument(
        "--all",
        action="store_true",
        help="also what the default leaves out for time: recognition at 1,000 objects, the roll section's "
        "untrained model, detection at 100 objects, the milvus, memory and fit sections",
    )
    p.add_argument("--models", type=Path, default=Path("models"), help="folder of posedesc-*.onnx models")
    p.add_argument("--modality", choices=("rgb", "depth", "rgbd"), default="rgb", help="the model measured")
    p.add_argument(
        "--objects", default=None, help="object counts for the LineMOD comparison (8,100; --all: 8,100,1000)"
    )
    p.add_argument(
        "--linemod-max-objects",
        type=int,
        default=None,
        help="measure LineMOD only up to this many objects (its build takes ~0.6 ms a template)",
    )
    p.add_argument("--max-templates", type=float, default=None, help="largest k-NN store (1e7)")
    p.add_argument("--concurrency", default=None, help="HTTP clients at once, e.g. 1,4,8")
    p.add_argument("--requests", type=int, default=None, help="HTTP requests per concurrency level and round")
    p.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="timed repetitions of slow measurements (throughput passes, LineMOD, registrations)",
    )
    p.add_argument(
        "--roll-models",
        default=None,
        help="models of the roll section, comma-separated: shipped (the --models folder's), untrained "
        "(a stand-in exported now: the coming design, 32-d, inplane_step in its metadata) or .onnx paths "
        "(default shipped; --all: shipped,untrained)",
    )
    p.add_argument(
        "--roll-objects", type=int, default=None, help="objects in the roll section's stores (100)"
    )
    p.add_argument(
        "--detect-objects",
        default=None,
        help="objects registered in the detect section (LM-O meshes, then generated shapes; 8; --all: 8,100)",
    )
    p.add_argument(
        "--memory-objects",
        default=None,
        help="objects in the stores of the memory section, the slope taken between the first and last "
        "(100,1000)",
    )
    p.add_argument(
        "--fit-frames",
        default=None,
        help="LM-O scene 2 frames of the fit section, comma-separated (default: the rgb model's val frames)",
    )
    p.add_argument("--query-turns", default=None, help="query turns of the roll section (1,2,3)")
    p.add_argument(
        "--profile",
        type=Path,
        default=None,
        metavar="DIR",
        help="profile one query of the roll section (its primary model, in-plane templates, the first "
        "query-turn count) into DIR: calls.prof (cProfile, 20 calls), top.txt (the 20 functions of most "
        "self time), flame.png and stacks.txt (a flame graph of stacks sampled every 1 ms)",
    )
    p.add_argument("--milvus-uri", default=None,
                   help="the milvus section against this Milvus (default: the PyPI server, started for the run)")  # fmt: skip
    p.add_argument("--milvus-templates", default=None,
                   help="large store sizes of the milvus section, templates (default 1e6; none: only the 100 objects)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="seed of the generated data")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from benchmarks.suite import run as run_bench
    from benchmarks.table import render

    cfg = configure(args)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    result = run_bench(cfg)
    print(render(result))
    args.json.write_text(json.dumps(result, indent=1) + "\n")
    print(f"\nwrote {args.json}")
    return 0


def configure(args: argparse.Namespace) -> BenchConfig:
    """The run the arguments ask for: the default, --all or --quick, then each size given."""
    from benchmarks.objects import VARIANTS
    from benchmarks.suite import SECTIONS, BenchConfig

    cfg = BenchConfig(models=args.models, modality=args.modality, seed=args.seed)
    if args.all:
        cfg = cfg.everything()
    if args.quick:
        cfg = cfg.tiny()
    if args.only:
        only = tuple(s.strip() for s in args.only.split(",") if s.strip())
        unknown = [s for s in only if s not in SECTIONS]
        if unknown or not only:
            raise UserError(f"--only {args.only}: sections are {', '.join(SECTIONS)}")
        cfg = replace(cfg, sections=tuple(s for s in SECTIONS if s in only))
    if args.objects:
        cfg = replace(cfg, recognition=replace(cfg.recognition, counts=_ints(args.objects)))
    if args.linemod_max_objects is not None:
        cfg = replace(cfg, recognition=replace(cfg.recognition, linemod_max_objects=args.linemod_max_objects))
    if args.max_templates is not None:
        sizes = tuple(n for n in cfg.knn.sizes if n <= args.max_templates) or (int(args.max_templates),)
        cfg = replace(cfg, knn=replace(cfg.knn, sizes=sizes))
    if args.concurrency:
        cfg = replace(cfg, http=replace(cfg.http, concurrency=_ints(args.concurrency)))
    if args.requests is not None:
        cfg = replace(cfg, http=replace(cfg.http, requests=max(1, args.requests)))
    if args.repeats is not None:
        n = max(1, args.repeats)
        cfg = replace(
            cfg,
            register_repeats=n,
            descriptor=replace(cfg.descriptor, repeats=n),
            recognition=replace(cfg.recognition, linemod_repeats=n),
        )
    if args.roll_models:
        specs = tuple(x.strip() for x in args.roll_models.split(",") if x.strip())
        if not specs:
            raise UserError(f"--roll-models {args.roll_models!r}: no model given")
        cfg = replace(cfg, roll=replace(cfg.roll, models=specs))
    if args.roll_objects is not None:
        if args.roll_objects <= 0:
            raise UserError(f"--roll-objects {args.roll_objects}: must be positive")
        cfg = replace(cfg, roll=replace(cfg.roll, objects=args.roll_objects))
    if args.detect_objects:
        cfg = replace(cfg, detect=replace(cfg.detect, counts=_ints(args.detect_objects)))
    if args.memory_objects:
        cfg = replace(cfg, memory=replace(cfg.memory, counts=_ints(args.memory_objects)))
    if args.fit_frames:
        cfg = replace(cfg, fit=replace(cfg.fit, frames=_ints(args.fit_frames)))
    if args.query_turns:
        turns = _ints(args.query_turns)
        if max(turns) > 36:
            raise UserError(f"--query-turns {args.query_turns}: at most 36 (the service's limit)")
        cfg = replace(cfg, roll=replace(cfg.roll, query_turns=turns))
    if args.profile is not None:
        if "roll" not in cfg.sections:
            raise UserError("--profile profiles the roll section: add roll to --only")
        cfg = replace(cfg, roll=replace(cfg.roll, profile=args.profile))
    if args.milvus_uri:
        cfg = replace(cfg, milvus=replace(cfg.milvus, uri=args.milvus_uri))
    if args.milvus_templates:
        large = () if args.milvus_templates == "none" else _ints(args.milvus_templates)
        cfg = replace(cfg, milvus=replace(cfg.milvus, large=large))
    if cfg.distinct is not None:  # --quick: few shapes, but enough for the largest count
        needed = max(cfg.recognition.counts) if "recognition" in cfg.sections else 0
        cfg = replace(cfg, distinct=max(cfg.distinct, -(-needed // VARIANTS)))
    return cfg
