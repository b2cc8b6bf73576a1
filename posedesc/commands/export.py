"""Export a training run to one ONNX file, with its metadata.

The patch conventions (modality, window, size, in-plane step), the data split and the provenance go into
the model's metadata.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from posedesc.cli import UserError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", type=Path, nargs="?", help="run folder of `posedesc train` (omitted with --onto)")
    p.add_argument("--out", type=Path, required=True, help="MODEL.onnx")
    p.add_argument(
        "--checkpoint",
        choices=("best", "last"),
        default="best",
        help="best: the epoch chosen on the validation frames; last: the final one",
    )

    p.add_argument(
        "--mask",
        type=Path,
        default=None,
        help="run folder of `posedesc train --arch mask`: its best head goes into the model, and the "
        "service blacks out what is not the centred object before describing a patch",
    )

    p.add_argument(
        "--local",
        type=Path,
        default=None,
        help="with --onto: run folder of `posedesc train --arch local`: its best trunk copy makes the "
        "model's local features (what the service re-ranks by)",
    )
    p.add_argument(
        "--onto",
        type=Path,
        default=None,
        metavar="MODEL.onnx",
        help="put the --mask head (one trained with --mask-finetune) into this exported rgb model, or join "
        "this RGB-D model's depth mask, and/or the --local features, without the descriptor's run "
        "(training/heads/graft.py)",
    )
    p.add_argument(
        "--as-rgbd",
        default=None,
        metavar="NEAR:FAR",
        help="write a colour trunk run as an RGB-D model: colour through the network, the mask from "
        "depth between NEAR mm in front of the surface at the centre and FAR mm behind it",
    )


def _near_far(text: str) -> tuple[float, float]:
    try:
        near, far = (float(v) for v in text.split(":"))
    except ValueError:
        raise UserError(f"--as-rgbd takes NEAR:FAR in mm, e.g. 40:90; got {text!r}") from None
    if near < 0 or far <= 0:
        raise UserError(f"--as-rgbd: NEAR must be >= 0 and FAR > 0 mm; got {text!r}")
    return near, far


def run(args: argparse.Namespace) -> int:
    if args.onto is not None:
        return _graft(args)
    if args.run is None:
        raise UserError("give the training run folder to export (or --onto MODEL.onnx with --mask)")
    if not (args.run / "checkpoint.pt").is_file():
        raise UserError(f"{args.run} has no checkpoint.pt: not a training run folder")
    if args.mask is not None and not (args.mask / "mask.pt").is_file():
        raise UserError(f"{args.mask} has no mask.pt: not a `posedesc train --arch mask` run folder")
    from training.export import export_onnx
    from training.train import load_checkpoint

    which = "best" if args.checkpoint == "best" and (args.run / "best.pt").is_file() else "checkpoint"
    net, ckpt = load_checkpoint(args.run, which)
    extra = {
        "command": ckpt.get("command", ""),
        "epoch": str(ckpt["epoch"]),
        "steps": str(ckpt["step"]),
        "checkpoint": "best on validation frames" if which == "best" else "last",
        "arch": ckpt["config"].get("arch", "paper"),
    }
    if ckpt.get("val"):
        extra["validation"] = json.dumps(ckpt["val"])
    cfg_path = args.run / "config.json"
    if cfg_path.is_file():
        c = json.loads(cfg_path.read_text())
        extra["data"] = json.dumps(c["data"])
        if "split_frames" in c:
            extra["split_frames"] = json.dumps(c["split_frames"])
        step = c["config"]["data"].get("template_inplane_step", 0.0)
        if c["config"]["data"].get("roll", 0.0) >= 180.0 and step > 0:
            extra["inplane_step"] = str(step)  # the service stores in-plane variants this far apart
        extra["code"] = c.get("code", "")
    report = args.run / "report.json"
    if report.is_file():
        r = json.loads(report.read_text())
        extra["train_minutes"] = str(r.get("train_minutes", ""))
        extra["objects"] = json.dumps(r.get("objects", []))
        extra["excluded_objects"] = json.dumps(r.get("excluded_objects", []))
        extra["code"] = r.get("code", "")
        for k in ("real_val", "synthetic_unseen_demo_shapes", "synthetic_bop_objects"):
            if k in r:
                extra[k] = json.dumps({a: b for a, b in r[k].items() if a != "bands"})
    head = None
    if args.mask is not None:
        from training.heads.mask import load_mask

        mask_net, mask_state = load_mask(args.mask)
        head = mask_net
        extra["mask"] = json.dumps(
            {
                "step": mask_state["step"],
                "val_iou": round(mask_state["val_iou"], 4),
                "command": mask_state.get("command", ""),
                "code": mask_state.get("code", ""),
            }
        )
    depth_mask = None if args.as_rgbd is None else _near_far(args.as_rgbd)
    if depth_mask is not None:
        extra["mask"] = json.dumps({"from": "depth", "near_mm": depth_mask[0], "far_mm": depth_mask[1]})
    try:
        out = export_onnx(net, args.out, ckpt["window_mm"], extra, mask=head, depth_mask=depth_mask)
    except ValueError as e:
        raise UserError(str(e)) from None
    print(f"{args.run} -> {out} ({out.stat().st_size / 1e6:.2f} MB)")
    return 0


def _graft(args: argparse.Namespace) -> int:
    if args.run is not None or args.as_rgbd is not None:
        raise UserError("--onto takes the model, --mask and --local only: no run folder, no --as-rgbd")
    if args.mask is None and args.local is None:
        raise UserError(
            "--onto needs --mask MASK_RUN (`posedesc train --arch mask`) or --local LOCAL_RUN (--arch local)"
        )
    if args.mask is not None and not (args.mask / "mask.pt").is_file():
        raise UserError(f"--mask: {args.mask} has no mask.pt: not a `posedesc train --arch mask` run folder")
    if args.local is not None and not (args.local / "local.pt").is_file():
        raise UserError(
            f"--local: {args.local} has no local.pt: not a `posedesc train --arch local` run folder"
        )
    if not args.onto.is_file():
        raise UserError(f"--onto: no such model file: {args.onto}")
    import tempfile

    from training.heads.graft import graft_local, graft_mask
    from training.heads.local import load_local
    from training.heads.mask import load_mask

    try:
        with tempfile.TemporaryDirectory() as tmp:
            model = args.onto
            if args.mask is not None:
                mask_net, state = load_mask(args.mask)
                about = _about(state, "val_iou") | {"onto": args.onto.name}
                model = graft_mask(
                    model, mask_net, args.out if args.local is None else Path(tmp) / "m.onnx", about
                )
            if args.local is not None:
                trunk, state = load_local(args.local)
                model = graft_local(
                    model, trunk, args.out, _about(state, "val_top1") | {"onto": args.onto.name}
                )
    except (ValueError, OSError) as e:
        raise UserError(str(e)) from None
    parts = " + ".join(str(p) for p in (args.mask, args.local) if p is not None)
    print(f"{args.onto} + {parts} -> {model} ({model.stat().st_size / 1e6:.2f} MB)")
    return 0


def _about(state: dict, score: str) -> dict:
    """What a grafted part's metadata entry says of its run."""
    return {
        "step": state["step"],
        score: round(state[score], 4),
        "command": state.get("command", ""),
        "code": state.get("code", ""),
    }
