"""Train a descriptor network (BOP data, procedural shapes).

The paper's method (Wohlhart & Lepetit 2015) in PyTorch on BOP meshes and frames plus procedural shapes;
the run folder gets checkpoints, a log and a report. `--resume` continues a killed run from its last
checkpoint (the same command with `--resume`)."""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

from posedesc.cli import UserError

if TYPE_CHECKING:
    from training.heads.local import LocalConfig
    from training.heads.mask import MaskConfig
    from training.train import TrainConfig
from posedesc.commands.train_options import OPTIONS, add_arguments

__all__ = ["add_arguments", "check_run_folder", "configs", "run"]


CHECKPOINTS = ("checkpoint.pt", "best.pt", "mask.pt", "mask-best.pt", "local.pt", "local-best.pt")


#: the checkpoint a run of each architecture resumes from (the descriptor's otherwise)
RESUMES = {"mask": "mask.pt", "local": "local.pt"}


def check_run_folder(
    out: Path, arch: str, resume: bool, config: dict, mask_config: dict, data: list[str]
) -> None:
    """Refuses (UserError) to train over a run without --resume, or to resume what cannot be: no
    checkpoint, other settings (`config`: the command's TrainConfig as a dict; `mask_config`: its
    MaskConfig's for --arch mask, its LocalConfig's for --arch local; `data`: the dataset folders), or no
    budget left."""
    from training.resume import config_differences, describe, resume_state

    held = [c for c in CHECKPOINTS if (out / c).is_file()]
    if not resume:
        if held:
            raise UserError(
                f"{out} already holds a run ({held[0]}): add --resume to continue it, or choose another --out"
            )
        return
    if arch == "pca":
        raise UserError("--resume: --arch pca is fitted in one pass, there is nothing to resume")
    name = RESUMES.get(arch, "checkpoint.pt")
    if not (out / name).is_file():
        raise UserError(f"--resume: no {name} in {out}, nothing to resume (train without --resume)")
    recorded = out / "config.json"
    if recorded.is_file():  # the command's settings and data folders when the run started
        rec = json.loads(recorded.read_text())
        differ = config_differences(rec.get("config", {}), config)
        if differ:
            raise UserError(
                f"--resume: the run in {out} was made with other settings: {describe(differ, OPTIONS)}"
            )
        theirs = [str(Path(d).resolve()) for d in rec.get("data", [])]
        if theirs and theirs != [str(Path(d).resolve()) for d in data]:
            raise UserError(
                f"--resume: the run in {out} was trained on --data {' '.join(rec['data'])}, not {' '.join(data)}"
            )
    ckpt = _load(out / name)
    try:
        resume_state(ckpt, mask_config if arch in RESUMES else config, OPTIONS, str(out / name))
    except ValueError as e:
        raise UserError(f"--resume: {e}") from None


@contextmanager
def _resume_hint(checkpoint: Path) -> Iterator[None]:
    """On Ctrl-C, says how to go on (the CLI then prints "interrupted" and exits 130)."""
    try:
        yield
    except KeyboardInterrupt:
        if checkpoint.is_file():
            step = _load(checkpoint)["step"]
            print(
                f"the last checkpoint is step {step}: the same command with --resume goes on from it",
                file=sys.stderr,
            )
        raise


def _load(path: Path) -> dict:
    import torch

    return torch.load(path, map_location="cpu", weights_only=False)


def _code_version() -> str:
    """The commit the training code came from (with "+changes" when the tree was not clean), or ""."""
    import subprocess

    root = Path(__file__).resolve().parents[2]
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True
        )
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=root, capture_output=True, text=True)
    except OSError:
        return ""
    if head.returncode != 0:
        return ""
    return head.stdout.strip() + ("+changes" if dirty.stdout.strip() else "")


def configs(args: argparse.Namespace) -> tuple[TrainConfig, MaskConfig | LocalConfig]:
    """The trainers' configs for the command's options: the descriptor's, and the mask head's or (--arch
    local) the local features' trainer's."""
    from training.data import DataConfig
    from training.heads.mask import MaskConfig
    from training.splits import SplitConfig
    from training.train import TrainConfig

    if args.arch in ("mask", "local") and args.modality != "rgb":
        raise UserError(f"--arch {args.arch}: it reads colour; train it with --modality rgb")
    if args.query_mask is not None and args.arch != "local":
        raise UserError("--query-mask is for --arch local")
    if args.query_mask is not None and args.query_mask.suffix == ".onnx":
        if not args.query_mask.is_file():
            raise UserError(f"--query-mask: no such model file: {args.query_mask}")
    elif args.query_mask is not None and not (args.query_mask / "mask.pt").is_file():
        raise UserError(
            f"--query-mask: {args.query_mask} has no mask.pt: not a `posedesc train --arch mask` run "
            "nor an .onnx model"
        )
    if args.mask_jitter and args.arch != "local":
        raise UserError("--mask-jitter is for --arch local")
    if args.mask_jitter < 0:
        raise UserError(f"--mask-jitter must be >= 0, got {args.mask_jitter:g}")
    defaults = {"local_same": 9, "local_far": 25.0, "local_others": 3, "local_others_real": 0.0}
    if args.arch != "local" and (given := [k for k, v in defaults.items() if getattr(args, k) != v]):
        raise UserError(f"--{given[0].replace('_', '-')} is for --arch local")
    if args.local_others < 0 or args.local_same < 0:
        raise UserError(
            f"--local-same and --local-others must be >= 0, got {args.local_same}, {args.local_others}"
        )
    if not 0.0 < args.local_far < 180.0:
        raise UserError(f"--local-far is an angle in (0, 180) deg, got {args.local_far:g}")
    if not 0.0 <= args.local_others_real <= 1.0:
        raise UserError(f"--local-others-real is a share in [0, 1], got {args.local_others_real:g}")
    if args.hard_negatives is not None and args.arch != "local":
        raise UserError("--hard-negatives is for --arch local")
    if args.hard_negatives is not None and not args.hard_negatives.is_file():
        raise UserError(f"--hard-negatives: no such model file: {args.hard_negatives}")
    if args.shapes < 0 or args.simple_shapes < 0:
        raise UserError("--shapes and --simple-shapes count objects: 0 or more")
    arch = args.arch if args.modality == "rgb" else "paper"  # the pretrained trunk takes colour only
    dim = args.dim or {"trunk": 32, "pca": 64}.get(arch, 16)
    try:
        exclude = tuple(int(x) for x in args.exclude_objects.split(",") if x.strip())
    except ValueError:
        raise UserError(
            f"--exclude-objects takes comma-separated object ids, not {args.exclude_objects!r}"
        ) from None
    data_cfg = DataConfig(
        shapes=args.shapes,
        simple_shapes=args.simple_shapes,
        split=SplitConfig(val=args.val, test=args.test),
        seed=args.seed,
        exclude=exclude,
        roll=args.roll,
        template_inplane_step=args.inplane_step,
    )
    cfg = TrainConfig(
        modality=args.modality,
        arch=arch,
        pool=args.pool,
        descriptor_dim=dim,
        minutes=args.minutes,
        max_steps=args.max_steps,
        samples_per_batch=args.batch,
        lr=args.lr,
        threads=args.threads,
        seed=args.seed,
        data=data_cfg,
    )
    if args.mask_finetune < 0:
        raise UserError(f"--mask-finetune must be >= 0, got {args.mask_finetune:g}")
    for flag, value in (
        ("--mask-outline", args.mask_outline),
        ("--mask-soft-edges", args.mask_soft_edges),
        ("--mask-colour-jitter", args.mask_colour_jitter),
    ):
        if value and args.arch != "mask":
            raise UserError(f"{flag} is for --arch mask")
        if value < 0:
            raise UserError(f"{flag} must be >= 0, got {value:g}")
    if args.mask_soft_edges > 1:
        raise UserError(f"--mask-soft-edges is a chance, at most 1, got {args.mask_soft_edges:g}")
    mcfg = MaskConfig(
        minutes=args.minutes,
        max_steps=args.max_steps,
        threads=args.threads,
        seed=args.seed,
        finetune=args.mask_finetune,
        outline_weight=args.mask_outline,
        soft_edges=args.mask_soft_edges,
        colour_jitter=args.mask_colour_jitter,
    )
    if args.arch == "local":
        from training.heads.local import LocalConfig

        query_mask = "" if args.query_mask is None else str(args.query_mask.resolve())
        lcfg = LocalConfig(
            minutes=args.minutes,
            max_steps=args.max_steps,
            threads=args.threads,
            seed=args.seed,
            query_mask=query_mask,
            mask_jitter=args.mask_jitter,
            same=args.local_same,
            far=args.local_far,
            others=args.local_others,
            others_real=args.local_others_real,
            hard_model="" if args.hard_negatives is None else str(args.hard_negatives.resolve()),
        )
        return cfg, lcfg
    return cfg, mcfg


def run(args: argparse.Namespace) -> int:
    for d in args.data:
        if not (d / "models" / "models_info.json").is_file():
            raise UserError(f"{d} is not a BOP dataset (no models/models_info.json)")
    from training.render_cache import build
    from training.train import train
    from training.validate import validate_real, validate_synthetic

    cfg, mcfg = configs(args)
    arch, exclude = cfg.arch, cfg.data.exclude
    # before the data, which takes minutes to render or load
    check_run_folder(args.out, arch, args.resume, asdict(cfg), asdict(mcfg), [str(d) for d in args.data])
    command = (
        "posedesc " + shlex.join(sys.argv[1:]) if sys.argv[0].endswith("posedesc") else shlex.join(sys.argv)
    )
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    data = build(args.data, cfg.data, args.cache)
    data_minutes = (time.perf_counter() - t0) / 60
    (args.out / "config.json").write_text(
        json.dumps(
            {
                "config": asdict(cfg),
                "data": [str(d) for d in args.data],
                "command": command,
                "split_frames": data.split_frames,
                "code": _code_version(),
            },
            indent=2,
        )
    )
    has_real = bool(data.test_instances())

    def validate(net, template_f):
        from training.export import torch_descriptors

        acc, _ = validate_real(
            data, lambda x: torch_descriptors(net, x), args.modality, template_f=template_f
        )
        return acc.as_dict()

    t1 = time.perf_counter()
    if arch == "mask":
        from training.heads.mask import MaskConfig, train_mask

        with _resume_hint(args.out / "mask.pt"):
            assert isinstance(mcfg, MaskConfig)
            train_mask(mcfg, data, args.out, command, _code_version(), resume=args.resume)
        print(f"trained the mask head for {(time.perf_counter() - t1) / 60:.1f} min -> {args.out}")
        return 0
    if arch == "local":
        from training.heads.local import LocalConfig, OnnxMask, train_local
        from training.heads.mask import MaskNet, load_mask

        assert isinstance(mcfg, LocalConfig)
        head: MaskNet | OnnxMask | None = None
        if mcfg.query_mask.endswith(".onnx"):
            try:
                head = OnnxMask(Path(mcfg.query_mask), args.threads)
            except ValueError as e:
                raise UserError(f"--query-mask: {e}") from None
        elif mcfg.query_mask:
            head = load_mask(Path(mcfg.query_mask))[0]
        with _resume_hint(args.out / "local.pt"):
            train_local(mcfg, data, args.out, head, command, _code_version(), resume=args.resume)
        print(f"trained the local features for {(time.perf_counter() - t1) / 60:.1f} min -> {args.out}")
        return 0
    if arch == "pca":
        from training.heads.pca import run as fit_pca

        net = fit_pca(cfg, data, args.out, command)
    else:
        validation = None if args.no_validate or not has_real else validate
        with _resume_hint(args.out / "checkpoint.pt"):
            net = train(cfg, data, args.out, validation, command, resume=args.resume)
    train_minutes = (time.perf_counter() - t1) / 60
    report = {
        "command": command,
        "data": [str(d) for d in args.data],
        "split_frames": data.split_frames,
        "objects": data.names[: data.real_objects],
        "excluded_objects": list(exclude),
        "data_minutes": round(data_minutes, 1),
        "train_minutes": round(train_minutes, 1),
        "code": _code_version(),
    }
    if not args.no_validate:
        from index.templates.shapes import demo_shapes
        from training.export import torch_descriptors

        embed = lambda x: torch_descriptors(net, x)  # noqa: E731
        if has_real:
            acc, bands = validate_real(data, embed, args.modality)
            report["real_val"] = acc.as_dict() | {"bands": {k: v.as_dict() for k, v in bands.items()}}
            print(f"real validation frames (last epoch): {acc.line()}")
            for k, v in bands.items():
                print(f"  visibility {k}: {v.line()}")
        unseen = {k: (m, "none") for k, m in demo_shapes().items()}
        acc = validate_synthetic(unseen, embed, args.modality, backgrounds=data.backgrounds)
        report["synthetic_unseen_demo_shapes"] = acc.as_dict()
        print(f"synthetic, objects never trained on (demo shapes): {acc.line()}")
        from index.data.bop import BopDataset

        seen: dict = {}
        for root in args.data:
            ds = BopDataset(root)
            seen |= {f"{root.name}/{o}": (ds.mesh(o, max_faces=20000), ds.symmetry(o)) for o in ds.obj_ids}
        acc = validate_synthetic(seen, embed, args.modality, backgrounds=data.backgrounds)
        report["synthetic_bop_objects"] = acc.as_dict()
        print(f"synthetic, BOP objects at random viewpoints: {acc.line()}")
    (args.out / "report.json").write_text(json.dumps(report, indent=2))
    print(f"trained {args.modality} for {train_minutes:.1f} min (data {data_minutes:.1f} min) -> {args.out}")
    return 0
