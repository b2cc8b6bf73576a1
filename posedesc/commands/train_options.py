"""`posedesc train`'s options: every flag with its default and why, grouped as the run's configs."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    pass


def _blocks(text: str) -> tuple[tuple[float, float], ...]:
    try:
        out = tuple(tuple(float(x) for x in b.split(":")) for b in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError("use A:B,C:D with fractions of the frame order") from None
    if not all(len(b) == 2 and 0 <= b[0] < b[1] <= 1 for b in out):
        raise argparse.ArgumentTypeError("each block is A:B with 0 <= A < B <= 1")
    return out  # type: ignore[return-value]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--modality", choices=("rgb", "depth", "rgbd"), required=True)
    p.add_argument("--data", type=Path, nargs="+", required=True, help="BOP dataset folders (meshes, frames)")
    p.add_argument(
        "--out", type=Path, required=True, help="run folder: checkpoint.pt, log.jsonl, report.json"
    )
    p.add_argument("--minutes", type=float, default=25.0, help="wall-clock budget of the optimisation")
    p.add_argument("--max-steps", type=int, default=0, help="also stop after this many batches (0: no limit)")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--arch", choices=("paper", "trunk", "pca", "mask", "local"), default="trunk",
                   help="trunk: frozen ImageNet MobileNetV2 stages + trained head (colour only); "
                   "mask: the foreground-mask head on the same stages (training/mask.py; "
                   "the export command adds it to a model); "
                   "local: a copy of the stages fine-tuned for the re-ranking's local similarity "
                   "(training/local.py; the export command puts it into a model); "
                   "pca: the same stages' map, pooled and projected on principal components of "
                   "procedural shapes' templates, no metric training (colour only); "
                   "paper: the paper's network (the baseline; depth and rgbd)")  # fmt: skip
    p.add_argument("--pool", type=int, default=2, help="pca: average pooling of the trunk's map")
    p.add_argument("--dim", type=int, default=None, help="descriptor dimension (default: 32 trunk, 16 paper)")
    p.add_argument("--roll", type=float, default=180.0, help="samples turn in-plane within +-this, deg")
    p.add_argument("--inplane-step", type=float, default=30.0,
                   help="deg between the in-plane variants of a template (0: upright only)")  # fmt: skip
    p.add_argument("--shapes", type=int, default=40, help="procedural objects besides the BOP meshes")
    p.add_argument("--simple-shapes", type=int, default=0,
                   help="more procedural objects, each one solid (a box, a can...) of random proportions")  # fmt: skip
    p.add_argument("--batch", type=int, default=48, help="training samples per batch")
    p.add_argument(
        "--lr", type=float, default=1e-3, help="Adam learning rate, decayed (cosine) over the budget"
    )
    p.add_argument("--threads", type=int, default=2, help="torch threads")
    p.add_argument(
        "--mask-finetune",
        type=float,
        default=0.0,
        help="mask heads (arch mask): also train a copy of the trunk and the later stages, at the learning "
        "rate times this (0: frozen, shared with the descriptor)",
    )
    p.add_argument(
        "--mask-outline",
        type=float,
        default=0.0,
        metavar="W",
        help="mask heads (arch mask): the loss of pixels within 2 px of the true outline counts 1 + W times",
    )
    p.add_argument(
        "--mask-soft-edges",
        type=float,
        default=0.0,
        metavar="P",
        help="mask heads (arch mask): the chance a synthetic sample's object is blended into its background "
        "over a soft edge shifted per colour channel, as a camera's edges are",
    )
    p.add_argument(
        "--mask-colour-jitter",
        type=float,
        default=0.0,
        metavar="S",
        help="mask heads (arch mask): random gamma, saturation, contrast and hue of the samples, of this strength",
    )
    p.add_argument(
        "--query-mask",
        type=Path,
        default=None,
        metavar="MASK_RUN|MODEL.onnx",
        help="--arch local: black the queries outside this `--arch mask` run's masks, or an exported model's "
        "(its mask output), as the service does (default: outside their true masks)",
    )
    p.add_argument(
        "--mask-jitter",
        type=float,
        default=0.0,
        metavar="PX",
        help="local features (arch local): move the training queries' mask outlines in and out by up to PX "
        "pixels, at random (the service's masks of new frames are wrong mostly along the outline)",
    )
    p.add_argument(
        "--hard-negatives",
        type=Path,
        default=None,
        metavar="MODEL.onnx",
        help="--arch local: also compare each query with templates near it in this exported model's "
        "descriptor space (the candidates the service re-ranks)",
    )
    p.add_argument(
        "--local-same",
        type=int,
        default=9,
        metavar="N",
        help="local features (arch local): negatives of the query's own object (half of them within 70 deg) a training query "
        "(default: %(default)s)",
    )
    p.add_argument(
        "--local-far",
        type=float,
        default=25.0,
        metavar="DEG",
        help="local features (arch local): a template of the query's object this far from its pose is a negative "
        "(default: %(default)s)",
    )
    p.add_argument(
        "--local-others",
        type=int,
        default=3,
        metavar="N",
        help="local features (arch local): negatives of other objects a training query is compared with (default: %(default)s)",
    )
    p.add_argument(
        "--local-others-real",
        type=float,
        default=0.0,
        metavar="F",
        help="local features (arch local): the share of those drawn from objects with real frames (the rest from every "
        "other object, procedural shapes mostly) (default: %(default)s)",
    )
    p.add_argument(
        "--val",
        type=_blocks,
        default=((0.20, 0.40),),
        help="validation blocks of each scene's frame order, as fractions: A:B,C:D (choose on these)",
    )
    p.add_argument(
        "--test",
        type=_blocks,
        default=((0.70, 0.90),),
        help="test blocks of each scene's frame order (report on these; training never sees them)",
    )
    p.add_argument(
        "--exclude-objects",
        default="",
        help="BOP object ids to leave out of training (comma-separated), to measure objects never seen",
    )
    p.add_argument("--cache", type=Path, default=Path("runs/cache"), help="rendered training data cache")
    p.add_argument("--no-validate", action="store_true", help="skip the per-epoch and final validation")
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --out from its last checkpoint (checkpoint.pt; mask.pt, local.pt for --arch "
        "mask, local): "
        "weights, optimiser, steps, time spent, best score, random states; the log is appended",
    )


# the command's option for each config field, to name them when a resumed run's settings differ
OPTIONS = {
    "modality": "--modality",
    "arch": "--arch",
    "descriptor_dim": "--dim",
    "pool": "--pool",
    "minutes": "--minutes",
    "max_steps": "--max-steps",
    "samples_per_batch": "--batch",
    "lr": "--lr",
    "seed": "--seed",
    "data.shapes": "--shapes",
    "data.simple_shapes": "--simple-shapes",
    "data.roll": "--roll",
    "data.template_inplane_step": "--inplane-step",
    "data.exclude": "--exclude-objects",
    "data.seed": "--seed",
    "data.split.val": "--val",
    "data.split.test": "--test",
    "finetune": "--mask-finetune",
    "outline_weight": "--mask-outline",
    "soft_edges": "--mask-soft-edges",
    "colour_jitter": "--mask-colour-jitter",
    "query_mask": "--query-mask",
    "mask_jitter": "--mask-jitter",
    "hard_model": "--hard-negatives",
    "same": "--local-same",
    "far": "--local-far",
    "others": "--local-others",
    "others_real": "--local-others-real",
}
