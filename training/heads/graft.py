"""A mask head put into a model already exported, without the descriptor's training run.

A mask head fine-tuned with its own copy of the trunk (`posedesc train --arch mask --mask-finetune`)
reads nothing but the patch, so its graph can replace the mask of an exported rgb model, or join an RGB-D
model's depth mask (`posedesc export --as-rgbd`): there a pixel is the centred object's where the depth
band and the learnt mask both say so (the minimum of the two logits is positive). The descriptor and the
local features are the exported model's, node for node, so a store's templates stay valid (the
fingerprint of the file changes, and the service embeds the templates again once, as for any new file).
The open-set calibration (`reject_above`) is dropped: it was measured with the old mask's scores
(`scripts/calibrate_reject.py` makes it again).
`posedesc export --onto MODEL.onnx --mask MASK_RUN --out NEW.onnx`.
"""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import onnx
import torch
from torch import nn

from index.features.embed import INPUT_NAME, LOCAL_NAME, MASK_NAME, ModelInfo
from training.heads.mask import MaskNet

MASK_PREFIX, LOCAL_PREFIX = "mask_graft/", "local_graft/"


class LearntMask(nn.Module):
    """The head on the colour channels. Shape: (B, C, S, S) -> (B, 1, S, S) logits."""

    def __init__(self, mask: MaskNet):
        super().__init__()
        self.mask = mask

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.mask(x[:, :3])


class LearntAndDepthMask(LearntMask):
    """The head on the colour channels and the RGB-D model's depth band (`training.export.
    ColourAndDepthMask`, the same `lo`, `hi` in the network's depth units): positive where both are."""

    def __init__(self, mask: MaskNet, lo: float, hi: float):
        super().__init__(mask)
        self.lo, self.hi = lo, hi

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        d = x[:, 3:4]
        return torch.minimum(torch.minimum(d - self.lo, self.hi - d), self.mask(x[:, :3]))


def graft_mask(model: Path, mask: MaskNet, out: Path, about: dict | None = None) -> Path:
    """Writes `model` with its mask output replaced by `mask`'s (rgb) or joined to its depth band
    (rgbd) to `out`; `about` goes into the metadata's `mask` entry. Raises ValueError for a model or head
    that cannot take it."""
    if not mask.own_stem:
        raise ValueError(
            "this mask head shares the descriptor's frozen trunk: only a head trained with its own "
            "(--mask-finetune) can join an exported model; export it with the descriptor's run instead"
        )
    base = onnx.load(str(model))
    meta = {p.key: p.value for p in base.metadata_props}
    info = ModelInfo.from_metadata(meta)
    if LOCAL_NAME not in [o.name for o in base.graph.output] or info.modality not in ("rgb", "rgbd"):
        raise ValueError(f"{model} is not a colour trunk model (rgb, or rgbd from one): no mask head fits it")
    entry = {**(about or {})}
    module: nn.Module
    if info.modality == "rgbd":
        band = json.loads(meta.get("mask") or "{}")
        if band.get("from") != "depth":
            raise ValueError(
                f"{model} is an RGB-D model without a depth mask: not one `export --as-rgbd` wrote"
            )
        half = info.window_mm / 2
        module = LearntAndDepthMask(mask.eval(), -float(band["near_mm"]) / half, float(band["far_mm"]) / half)
        entry |= {"from": "depth and learnt", "near_mm": band["near_mm"], "far_mm": band["far_mm"]}
    else:
        module = LearntMask(mask.eval())
        entry |= {"from": "learnt"}
    # a calibration of the open-set threshold measured the old mask's scores: calibrate the new model again
    meta.pop("reject_above", None)
    return _splice(base, module, MASK_NAME, MASK_PREFIX, {**meta, "mask": json.dumps(entry)}, out)


class LocalMap(nn.Module):
    """A fine-tuned copy of the trunk's map, L2-normalised and flattened as `training.export.WithLocal`
    writes it, read from the colour channels. Shape: (B, C, S, S) -> (B, F)."""

    def __init__(self, trunk: nn.Module):
        super().__init__()
        self.trunk = trunk

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        flat = self.trunk(x[:, :3]).flatten(1)
        return flat / torch.sqrt((flat * flat).sum(dim=1, keepdim=True) + 1e-12)


def graft_local(model: Path, trunk: nn.Module, out: Path, about: dict | None = None) -> Path:
    """Writes `model` with its local features (`LOCAL_NAME`, what the re-ranking compares) made by
    `trunk` (a copy of the pretrained trunk fine-tuned for the re-ranking: `training.heads.local`) to `out`;
    `about` goes into the metadata's `local` entry. The descriptor and the mask are the model's, node for
    node; the map's shape must be the model's (the store's templates are re-embedded for the new file).
    Raises ValueError for a model without local features."""
    base = onnx.load(str(model))
    meta = {p.key: p.value for p in base.metadata_props}
    info = ModelInfo.from_metadata(meta)
    if LOCAL_NAME not in [o.name for o in base.graph.output] or info.modality not in ("rgb", "rgbd"):
        raise ValueError(
            f"{model} is not a colour trunk model (rgb, or rgbd from one): it has no local features"
        )
    meta.pop("reject_above", None)  # measured with the old features' scores
    return _splice(
        base,
        LocalMap(trunk.eval()),
        LOCAL_NAME,
        LOCAL_PREFIX,
        {**meta, "local": json.dumps(about or {})},
        out,
    )


def _splice(
    base: onnx.ModelProto, module: nn.Module, name: str, prefix: str, meta: dict[str, str], out: Path
) -> Path:
    """`base` with its output `name` made by `module` instead (its nodes under `prefix`), `meta` as its
    metadata, written to `out`."""
    info = ModelInfo.from_metadata(meta)
    channels = 4 if info.modality == "rgbd" else 3
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "part.onnx"
        torch.onnx.export(
            module.eval(),
            (torch.zeros(2, channels, info.size, info.size),),
            str(path),
            input_names=[INPUT_NAME],
            output_names=[name],
            dynamic_shapes={"x": {0: torch.export.Dim("batch", min=1, max=65536)}},
            external_data=False,
            dynamo=True,
        )
        part = onnx.load(str(path))
    opsets = {o.domain: o.version for o in base.opset_import}
    if any(opsets.get(o.domain, o.version) != o.version for o in part.opset_import):
        raise ValueError(
            "the model was exported with other operator sets than this torch writes: export it again"
        )
    keep = [o.name for o in base.graph.output if o.name != name]
    outputs = [o.name for o in base.graph.output]
    trimmed = onnx.utils.Extractor(base).extract_model([INPUT_NAME], keep)
    part = onnx.compose.add_prefix(part, prefix, rename_inputs=False, rename_outputs=False)
    by_name = {o.name: o for o in [*trimmed.graph.output, *part.graph.output]}
    graph = onnx.helper.make_graph(
        [*trimmed.graph.node, *part.graph.node],
        base.graph.name,
        list(base.graph.input),
        [by_name[o] for o in outputs],  # the outputs in the model's order
        initializer=[*trimmed.graph.initializer, *part.graph.initializer],
        value_info=[*trimmed.graph.value_info, *part.graph.value_info],
    )
    merged = onnx.helper.make_model(
        graph,
        opset_imports=[*base.opset_import, *(o for o in part.opset_import if o.domain not in opsets)],
        ir_version=base.ir_version,
    )
    onnx.checker.check_model(merged)
    for k, v in meta.items():
        merged.metadata_props.add(key=k, value=v)
    out.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(merged, str(out))
    return out
