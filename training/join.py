"""Descriptor networks of one modality as one model: their descriptors side by side, scaled by 1/sqrt(n) for n
networks, so a squared distance is the mean of the networks' and the distances keep the scale the open-set
statistic's weights were chosen in. An experiment's tool (docs/experiments.md, "A second depth network"):
`.venv/bin/python -m training.join A.onnx B.onnx [C.onnx ...] --out JOINED.onnx`.

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


def join(paths: list[Path], out: Path) -> None:
    """Writes the joined model of `paths` (two or more) to `out`; ValueError when they cannot be joined."""
    if len(paths) < 2:
        raise ValueError("join needs two models or more")
    models = [onnx.load(str(p)) for p in paths]
    metas = [{p.key: p.value for p in m.metadata_props} for m in models]
    for path, meta in zip(paths[1:], metas[1:], strict=True):
        for key in ("modality", "window_mm", "size", "normalisation"):
            if meta.get(key) != metas[0].get(key):
                raise ValueError(
                    f"{paths[0].name} and {path.name} differ in {key}: {metas[0].get(key)} against {meta.get(key)}"
                )
    for m, path in zip(models, paths, strict=True):
        if [o.name for o in m.graph.output] != [DESCRIPTOR_NAME]:
            raise ValueError(f"{path.name} has outputs besides its descriptor: only descriptors are joined")
        if [i.name for i in m.graph.input] != [INPUT_NAME]:
            raise ValueError(f"{path.name} does not take one input {INPUT_NAME!r}")
    prefixes = [f"m{i}/" for i in range(len(models))]
    models = [compose.add_prefix(m, p, rename_inputs=False) for m, p in zip(models, prefixes, strict=True)]
    dims = [int(m.graph.output[0].type.tensor_type.shape.dim[1].dim_value) for m in models]
    joined = [
        helper.make_node("Concat", [p + DESCRIPTOR_NAME for p in prefixes], ["joined"], axis=1),
        helper.make_node("Mul", ["joined", "join/scale"], [DESCRIPTOR_NAME]),
    ]
    scale = helper.make_tensor("join/scale", onnx.TensorProto.FLOAT, [], [len(models) ** -0.5])
    graph = helper.make_graph(
        [n for m in models for n in m.graph.node] + joined,
        "joined",
        list(models[0].graph.input),
        [helper.make_tensor_value_info(DESCRIPTOR_NAME, onnx.TensorProto.FLOAT, ["batch", sum(dims)])],
        [t for m in models for t in m.graph.initializer] + [scale],
    )
    model = helper.make_model(graph, opset_imports=models[0].opset_import, ir_version=models[0].ir_version)
    meta = {k: v for k, v in metas[0].items() if k not in DROPPED}
    parts = ", ".join(f"{p.name} ({m.get('command', '?')})" for p, m in zip(paths, metas, strict=True))
    meta |= {
        "descriptor_dim": str(sum(dims)),
        "joined": f"{parts}: descriptors side by side / sqrt({len(paths)})",
    }
    for key, value in meta.items():
        model.metadata_props.add(key=key, value=value)
    onnx.checker.check_model(model)
    onnx.save(model, str(out))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("first", type=Path, help="a model whose metadata the joined one keeps")
    ap.add_argument("others", type=Path, nargs="+", help="one or more models of the same modality")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    paths = [args.first, *args.others]
    for path in paths:
        if not path.is_file():
            sys.exit(f"error: no such model: {path}")
    if not args.out.parent.is_dir():
        sys.exit(f"error: --out: no folder {args.out.parent}")
    try:
        join(paths, args.out)
    except (ValueError, onnx.checker.ValidationError) as e:
        sys.exit(f"error: {e}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
