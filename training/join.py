"""Two descriptor networks of one modality as one model: their descriptors side by side, scaled by 1/sqrt(2),
so a squared distance is the mean of the two networks' and the distances keep the scale the open-set
statistic's weights were chosen in. An experiment's tool (docs/experiments.md, "A second depth network"):
`.venv/bin/python -m training.join A.onnx B.onnx --out JOINED.onnx`.

The first model's metadata is kept, but for what was measured on its own descriptors: its open-set
calibration and its detections' confidence curve are dropped (`scripts/calibrate_reject.py` makes the first
again). Models with local features or a mask are refused: only the descriptor would be joined.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import onnx
from onnx import compose, helper

from index.features.embed import INPUT_NAME
from index.features.embed import OUTPUT_NAME as DESCRIPTOR_NAME

#: metadata measured on the first model's own descriptors, not the joined ones
DROPPED = ("reject_above", "detect_confidence")


def join(a: Path, b: Path, out: Path) -> None:
    """Writes the joined model of `a` and `b` to `out`; ValueError when they cannot be joined."""
    ma, mb = onnx.load(str(a)), onnx.load(str(b))
    meta_a = {p.key: p.value for p in ma.metadata_props}
    meta_b = {p.key: p.value for p in mb.metadata_props}
    for key in ("modality", "window_mm", "size", "normalisation"):
        if meta_a.get(key) != meta_b.get(key):
            raise ValueError(
                f"{a.name} and {b.name} differ in {key}: {meta_a.get(key)} against {meta_b.get(key)}"
            )
    for m, path in ((ma, a), (mb, b)):
        if [o.name for o in m.graph.output] != [DESCRIPTOR_NAME]:
            raise ValueError(f"{path.name} has outputs besides its descriptor: only descriptors are joined")
        if [i.name for i in m.graph.input] != [INPUT_NAME]:
            raise ValueError(f"{path.name} does not take one input {INPUT_NAME!r}")
    mb = compose.add_prefix(mb, "b/", rename_inputs=False)
    ma = compose.add_prefix(ma, "a/", rename_inputs=False)
    dims = [int(m.graph.output[0].type.tensor_type.shape.dim[1].dim_value) for m in (ma, mb)]
    joined = [
        helper.make_node("Concat", ["a/" + DESCRIPTOR_NAME, "b/" + DESCRIPTOR_NAME], ["joined"], axis=1),
        helper.make_node("Mul", ["joined", "join/scale"], [DESCRIPTOR_NAME]),
    ]
    graph = helper.make_graph(
        [*ma.graph.node, *mb.graph.node, *joined],
        "joined",
        list(ma.graph.input),
        [helper.make_tensor_value_info(DESCRIPTOR_NAME, onnx.TensorProto.FLOAT, ["batch", sum(dims)])],
        [
            *ma.graph.initializer,
            *mb.graph.initializer,
            helper.make_tensor("join/scale", onnx.TensorProto.FLOAT, [], [0.5**0.5]),
        ],
    )
    model = helper.make_model(graph, opset_imports=ma.opset_import, ir_version=ma.ir_version)
    meta = {k: v for k, v in meta_a.items() if k not in DROPPED}
    meta |= {"descriptor_dim": str(sum(dims)), "joined": f"{a.name} ({meta_a.get('command', '?')}) and "
             f"{b.name} ({meta_b.get('command', '?')}), descriptors side by side / sqrt(2)"}  # fmt: skip
    for key, value in meta.items():
        model.metadata_props.add(key=key, value=value)
    onnx.checker.check_model(model)
    onnx.save(model, str(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("first", type=Path, help="a model whose metadata the joined one keeps")
    ap.add_argument("second", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    for path in (args.first, args.second):
        if not path.is_file():
            sys.exit(f"error: no such model: {path}")
    if not args.out.parent.is_dir():
        sys.exit(f"error: --out: no folder {args.out.parent}")
    try:
        join(args.first, args.second, args.out)
    except (ValueError, onnx.checker.ValidationError) as e:
        sys.exit(f"error: {e}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
