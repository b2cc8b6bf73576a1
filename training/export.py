"""ONNX export of a trained run: one file, dynamic batch axis, patch conventions in its metadata."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from index.embed import INPUT_NAME, LOCAL_NAME, OUTPUT_NAME, ModelInfo
from training.model import DescriptorNet


class WithLocal(nn.Module):
    """The network and, as a second output, its frozen trunk's map L2-normalised and flattened: what
    the service re-ranks its nearest answers by (local similarity of early pretrained features, measured
    to double the answers within 20 deg on validation frames). Shape: (B, C, S, S) -> (B, D), (B, F)."""

    def __init__(self, net: DescriptorNet):
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        m = self.net.stem(x)
        flat = m.flatten(1)
        return self.net.body(m), flat / torch.sqrt((flat * flat).sum(dim=1, keepdim=True) + 1e-12)


def export_onnx(
    net: DescriptorNet, out: str | Path, window_mm: float, extra: dict[str, str] | None = None
) -> Path:
    """Writes `net` to `out` (.onnx) with metadata; returns the path."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cfg = net.cfg
    net = net.eval()
    dummy = torch.zeros(2, cfg.channels, cfg.size, cfg.size)
    local = not isinstance(net.stem, nn.Identity)  # a pretrained trunk: its map re-ranks
    torch.onnx.export(
        WithLocal(net) if local else net,
        (dummy,),
        str(out),
        input_names=[INPUT_NAME],
        output_names=[OUTPUT_NAME, LOCAL_NAME] if local else [OUTPUT_NAME],
        dynamic_shapes={"x": {0: torch.export.Dim("batch", min=1, max=65536)}},
        external_data=False,
        dynamo=True,
    )
    model = onnx.load(str(out))
    info = ModelInfo(cfg.modality, float(window_mm), cfg.size, cfg.descriptor_dim, dict(extra or {}))
    del model.metadata_props[:]
    for k, v in info.to_metadata().items():
        model.metadata_props.add(key=k, value=str(v))
    onnx.save(model, str(out))
    return out


def torch_descriptors(net: DescriptorNet, x: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return net.eval()(torch.from_numpy(np.ascontiguousarray(x, np.float32))).numpy()
