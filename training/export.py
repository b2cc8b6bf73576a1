"""ONNX export of a trained run: one file, dynamic batch axis, patch conventions in its metadata."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from index.features.embed import INPUT_NAME, LOCAL_NAME, MASK_NAME, OUTPUT_NAME, ModelInfo
from training.heads.mask import MaskNet
from training.model import DescriptorNet
from training.trunk import Trunk


class WithLocal(nn.Module):
    """The network and, as a second output, its frozen trunk's map L2-normalised and flattened: what
    the service re-ranks its nearest answers by (local similarity of early pretrained features, measured
    to double the answers within 20 deg on validation frames); with a mask head (`training/heads/mask.py`) on
    the same trunk (or on its own fine-tuned copy: `MaskNet.own_stem`), a third output: the logits of the
    centred object's pixels. Shape: (B, C, S, S) -> (B, D), (B, F)[, (B, 1, S, S)]."""

    def __init__(self, net: DescriptorNet, mask: MaskNet | None = None):
        super().__init__()
        self.net, self.mask = net, mask

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        if self.mask is None:
            m = self.net.stem(x)
        else:
            assert isinstance(self.net.stem, Trunk)  # export_onnx checked: a mask head needs the trunk
            early, m = self.net.stem.stages(x)
        flat = m.flatten(1)
        out = (self.net.body(m), flat / torch.sqrt((flat * flat).sum(dim=1, keepdim=True) + 1e-12))
        if self.mask is None:
            return out
        if self.mask.own_stem:
            return (*out, self.mask(x))
        return (*out, self.mask.head(early, m))


class ColourAndDepthMask(nn.Module):
    """A colour trunk model as an RGB-D one: the colour channels go through it (descriptor and local
    features, as the rgb model's), and the depth channel says where the centred object is: the mask's
    logits are positive where the depth lies between `near_mm` in front of the surface at the patch's
    centre and `far_mm` behind it (the input's depth channel is (d - surface) / (window / 2), empty +1;
    `index.features.patches.normalise_depth`). Clutter in front of or behind the object falls out of the
    re-ranking's score (`index.features.local.masked_cosine`). Shape: (B, 4, S, S) -> (B, D), (B, F), (B, 1, S, S)."""

    def __init__(self, net: DescriptorNet, near_mm: float, far_mm: float, window_mm: float):
        super().__init__()
        self.net = WithLocal(net)
        if not (0 <= near_mm < window_mm / 2 and 0 < far_mm < window_mm / 2):
            raise ValueError(
                f"the depth mask's near and far must be under half the window ({window_mm / 2:g} mm): the "
                "network's depth input is clipped there"
            )
        self.lo, self.hi = -near_mm / (window_mm / 2), far_mm / (window_mm / 2)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        desc, local = self.net(x[:, :3])
        d = x[:, 3:4]
        return desc, local, torch.minimum(d - self.lo, self.hi - d)


def export_onnx(
    net: DescriptorNet,
    out: str | Path,
    window_mm: float,
    extra: dict[str, str] | None = None,
    mask: MaskNet | None = None,
    depth_mask: tuple[float, float] | None = None,
) -> Path:
    """Writes `net` (and a mask head on its trunk) to `out` (.onnx) with metadata; returns the path.
    `depth_mask` (near, far mm): a colour trunk model written as an RGB-D model whose mask is cut from
    the depth channel (`ColourAndDepthMask`)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cfg = net.cfg
    net = net.eval()
    local = not isinstance(net.stem, nn.Identity)  # a pretrained trunk: its map re-ranks
    if (mask is not None or depth_mask is not None) and not local:
        raise ValueError("a mask head reads the pretrained trunk: export it with a trunk model")
    if mask is not None and depth_mask is not None:
        raise ValueError("one mask: a head on the colour trunk, or the depth's")
    modality, channels = ("rgbd", 4) if depth_mask is not None else (cfg.modality, cfg.channels)
    dummy = torch.zeros(2, channels, cfg.size, cfg.size)
    names = [OUTPUT_NAME, LOCAL_NAME] if local else [OUTPUT_NAME]
    module: nn.Module = WithLocal(net, None if mask is None else mask.eval()) if local else net
    if depth_mask is not None:
        module = ColourAndDepthMask(net, *depth_mask, window_mm)
    torch.onnx.export(
        module.eval(),
        (dummy,),
        str(out),
        input_names=[INPUT_NAME],
        output_names=names + ([MASK_NAME] if mask is not None or depth_mask is not None else []),
        dynamic_shapes={"x": {0: torch.export.Dim("batch", min=1, max=65536)}},
        external_data=False,
        dynamo=True,
    )
    model = onnx.load(str(out))
    extra = dict(extra or {})
    if depth_mask is not None:  # the band, for what reads the file (`training.heads.graft`)
        extra.setdefault(
            "mask", json.dumps({"from": "depth", "near_mm": depth_mask[0], "far_mm": depth_mask[1]})
        )
    info = ModelInfo(modality, float(window_mm), cfg.size, cfg.descriptor_dim, extra)
    del model.metadata_props[:]
    for k, v in info.to_metadata().items():
        model.metadata_props.add(key=k, value=str(v))
    onnx.save(model, str(out))
    return out


def torch_descriptors(net: DescriptorNet, x: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return net.eval()(torch.from_numpy(np.ascontiguousarray(x, np.float32))).numpy()
