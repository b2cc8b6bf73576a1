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

from index.embed import INPUT_NAME, LOCAL_NAME, MASK_NAME, ModelInfo
from training.mask import MaskNet

PREFIX = "mask_graft/"


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
    outputs = [o.name for o in base.graph.output]
    keep = [o for o in outputs if o != MASK_NAME]
    if LOCAL_NAME not in keep or info.modality not in ("rgb", "rgbd"):
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
    channels = 4 if info.modality == "rgbd" else 3
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "mask.onnx"
        torch.onnx.export(
            module.eval(),
            (torch.zeros(2, channels, info.size, info.size),),
            str(path),
            input_names=[INPUT_NAME],
            output_names=[MASK_NAME],
            dynamic_shapes={"x": {0: torch.export.Dim("batch", min=1, max=65536)}},
            external_data=False,
            dynamo=True,
        )
        head = onnx.load(str(path))
    opsets = {o.domain: o.version for o in base.opset_import}
    if any(opsets.get(o.domain, o.version) != o.version for o in head.opset_import):
        raise ValueError(
            f"{model} was exported with other operator sets than this torch writes: export it again"
        )
    trimmed = onnx.utils.Extractor(base).extract_model([INPUT_NAME], keep)
    head = onnx.compose.add_prefix(head, PREFIX, rename_inputs=False, rename_outputs=False)
    graph = onnx.helper.make_graph(
        [*trimmed.graph.node, *head.graph.node],
        base.graph.name,
        list(base.graph.input),
        [*trimmed.graph.output, *head.graph.output],
        initializer=[*trimmed.graph.initializer, *head.graph.initializer],
        value_info=[*trimmed.graph.value_info, *head.graph.value_info],
    )
    merged = onnx.helper.make_model(
        graph,
        opset_imports=[*base.opset_import, *(o for o in head.opset_import if o.domain not in opsets)],
        ir_version=base.ir_version,
    )
    onnx.checker.check_model(merged)
    # a calibration of the open-set threshold measured the old mask's scores: calibrate the new model again
    meta.pop("reject_above", None)
    for k, v in {**meta, "mask": json.dumps(entry)}.items():
        merged.metadata_props.add(key=k, value=v)
    out.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(merged, str(out))
    return out
