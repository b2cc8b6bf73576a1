"""Descriptor networks: patch -> descriptor.

- `paper`: Wohlhart & Lepetit's network, two conv + max-pool + ReLU stages, a 256-unit layer, a linear
  descriptor. Kept as the reproducible baseline row.
- `trunk`: a frozen ImageNet MobileNetV2 trunk (`training/trunk.py`, colour only) and a small trained
  head: two stride-2 3x3 convolutions 24 -> 48 -> 64 with BatchNorm, FC 1024 -> 256 -> D. The head keeps
  the map's layout until the last layers (pooling it away destroys the pose, measured in issue 11).
- `pca`: the same frozen trunk and nothing trained by the metric loss: its map average-pooled `pool` x
  `pool`, L2-normalised and projected on the principal components of the templates of procedural
  shapes (`training/heads/pca.py`). Template matching on early pretrained features, made compact enough for
  the index; it never sees a BOP object, so every object is one it was never trained on."""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import torch
from torch import nn

from index.features.patches import MODALITY_CHANNELS
from training.trunk import TRUNK_CHANNELS, Trunk

ARCHS = ("paper", "trunk", "pca")


@dataclass
class NetConfig:
    modality: str = "rgb"  # rgb (3 channels), depth (1) or rgbd (4)
    descriptor_dim: int = 16  # 3 for pictures, 32 as in the paper's table
    size: int = 64  # input side, px
    arch: str = "paper"  # see the module docstring
    pool: int = 2  # pca: average pooling of the trunk's map before the projection

    @property
    def channels(self) -> int:
        return MODALITY_CHANNELS[self.modality]


class DescriptorNet(nn.Module):
    """Patch -> descriptor: `body(stem(x))`. The stem is what training never changes (the frozen trunk;
    nothing for the paper's network), so training computes the templates' stems once and runs only the
    body on them. Shape: (B, C, S, S) -> (B, D)."""

    def __init__(self, cfg: NetConfig, pretrained: bool = True):
        super().__init__()
        self.cfg = cfg
        self.stem: nn.Module = nn.Identity()
        if cfg.arch == "pca":
            if cfg.modality != "rgb":
                raise ValueError("the pretrained trunk takes colour only: use --arch paper for depth/rgbd")
            self.stem = Trunk(pretrained)
            side = cfg.size // 4 // cfg.pool
            self.body = nn.Sequential(
                OrderedDict(
                    pool=nn.AvgPool2d(cfg.pool),
                    flat=nn.Flatten(),
                    unit=UnitLength(),
                    project=nn.Linear(TRUNK_CHANNELS * side * side, cfg.descriptor_dim),
                )
            )
            for p in self.body.parameters():
                p.requires_grad_(False)  # fitted by `training.heads.pca.fit`, not by gradients
            return
        if cfg.arch == "trunk":
            if cfg.modality != "rgb":
                raise ValueError("the pretrained trunk takes colour only: use --arch paper for depth/rgbd")
            side = cfg.size // 16  # /4 in the trunk, /4 in the head
            self.stem = Trunk(pretrained)
            features: nn.Module = nn.Sequential(
                nn.Conv2d(TRUNK_CHANNELS, 48, 3, 2, 1, bias=False),
                nn.BatchNorm2d(48),
                nn.ReLU(),
                nn.Conv2d(48, 64, 3, 2, 1, bias=False),
                nn.BatchNorm2d(64),
                nn.ReLU(),
            )
            flat = 64 * side * side
        elif cfg.arch == "paper":
            features = nn.Sequential(
                nn.Conv2d(cfg.channels, 16, kernel_size=8),  # 64 -> 57
                nn.MaxPool2d(2),  # -> 28
                nn.ReLU(),
                nn.Conv2d(16, 7, kernel_size=5),  # -> 24
                nn.MaxPool2d(2),  # -> 12
                nn.ReLU(),
            )
            side = ((cfg.size - 7) // 2 - 4) // 2
            flat = 7 * side * side
        else:
            raise ValueError(f"unknown arch {cfg.arch!r}; use one of {', '.join(ARCHS)}")
        head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(flat, 256),
            nn.ReLU(),
            nn.Linear(256, cfg.descriptor_dim),
        )
        self.body = nn.Sequential(OrderedDict(features=features, head=head))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(self.stem(x))


class UnitLength(nn.Module):
    """Rows scaled to unit L2 norm. Shape: (B, N) -> (B, N)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x / torch.sqrt((x * x).sum(dim=1, keepdim=True) + 1e-12)
