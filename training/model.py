"""The paper's network: two conv + max-pool + ReLU stages, a 256-unit layer, a linear descriptor."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from index.patches import MODALITY_CHANNELS


@dataclass
class NetConfig:
    modality: str = "rgb"  # rgb (3 channels), depth (1) or rgbd (4)
    descriptor_dim: int = 16  # 3 for pictures, 32 as in the paper's table
    size: int = 64  # input side, px

    @property
    def channels(self) -> int:
        return MODALITY_CHANNELS[self.modality]


class DescriptorNet(nn.Module):
    """Patch -> descriptor. Shape: (B, C, 64, 64) -> (B, D)."""

    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.cfg = cfg
        self.features = nn.Sequential(
            nn.Conv2d(cfg.channels, 16, kernel_size=8),  # 64 -> 57
            nn.MaxPool2d(2),  # -> 28
            nn.ReLU(),
            nn.Conv2d(16, 7, kernel_size=5),  # -> 24
            nn.MaxPool2d(2),  # -> 12
            nn.ReLU(),
        )
        side = ((cfg.size - 7) // 2 - 4) // 2
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(7 * side * side, 256),
            nn.ReLU(),
            nn.Linear(256, cfg.descriptor_dim),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(x))
