"""ONNX export of a trained run: one file, dynamic batch axis, patch conventions in its metadata."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import torch

from index.embed import INPUT_NAME, OUTPUT_NAME, ModelInfo
from training.model import DescriptorNet


def export_onnx(
    net: DescriptorNet, out: str | Path, window_mm: float, extra: dict[str, str] | None = None
) -> Path:
    """Writes `net` to `out` (.onnx) with metadata; returns the path."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cfg = net.cfg
    net = net.eval()
    dummy = torch.zeros(2, cfg.channels, cfg.size, cfg.size)
    torch.onnx.export(
        net,
        (dummy,),
        str(out),
        input_names=[INPUT_NAME],
        output_names=[OUTPUT_NAME],
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
