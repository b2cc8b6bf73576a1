"""The objectness network in torch: a small head on the frozen trunk's stride-8 and stride-16 maps, and its two losses."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from training.objectness.config import IMAGENET_MEAN, IMAGENET_STD
from training.trunk import DeepStages, Trunk


class ObjectnessHead(nn.Module):
    """Stride-8 features (and stride-16 upsampled) -> 5 maps. Shape: (B, 32, H/8, W/8), (B, 64, H/16,
    W/16) -> (B, 5, H/8, W/8): centre logit, dx, dy, log window, log extent."""

    def __init__(self, width: int = 64):
        super().__init__()

        def block(cin: int, dilation: int) -> nn.Sequential:
            return nn.Sequential(
                nn.Conv2d(cin, width, 3, padding=dilation, dilation=dilation, bias=False),
                nn.BatchNorm2d(width),
                nn.ReLU(inplace=True),
            )

        # dilations 1, 2, 4, 1 add 16 cells (128 px at stride 8) of receptive field
        self.body = nn.Sequential(block(32 + 64, 1), block(width, 2), block(width, 4), block(width, 1))
        self.out = nn.Conv2d(width, 5, 1)
        bias = self.out.bias
        assert bias is not None  # Conv2d's default
        with torch.no_grad():
            bias.zero_()
            bias[0] = -4.6  # a prior of 1 % centres: the focal loss starts calm (RetinaNet)

    def forward(self, d8: torch.Tensor, d16: torch.Tensor) -> torch.Tensor:
        up = F.interpolate(d16, scale_factor=2.0, mode="nearest")
        return self.out(self.body(torch.cat([d8, up], dim=1)))


class ObjectnessNet(nn.Module):
    """Frozen pretrained stages and the trained head. Shape: (B, 3, H, W) RGB 0-255, H and W multiples
    of 16 -> (B, 5, H/8, W/8) (raw: a logit in channel 0)."""

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, width: int = 64, pretrained: bool = True):
        super().__init__()
        self.trunk, self.deep = Trunk(pretrained), DeepStages(pretrained)
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1) * 255.0)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1) * 255.0)
        self.head = ObjectnessHead(width)

    def features(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.deep(self.trunk((x - self.mean) / self.std))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(*self.features(x))


class Scored(nn.Module):
    """What is exported: channel 0 as a score (sigmoid), the rest as they are."""

    def __init__(self, net: ObjectnessNet):
        super().__init__()
        self.net = net

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        y = self.net(rgb)
        return torch.cat([torch.sigmoid(y[:, :1]), y[:, 1:]], dim=1)


def centre_loss(logit: torch.Tensor, heat: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss (Zhou et al. 2019), per target. Shape: (B, G, G) x3."""
    p = torch.sigmoid(logit).clamp(1e-4, 1 - 1e-4)
    pos = heat >= 1.0
    pos_loss = -torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = -torch.log(1 - p) * p**2 * (1 - heat) ** 4 * (~pos)
    return ((pos_loss + neg_loss) * weight).sum() / pos.sum().clamp(min=1)


def regression_loss(
    pred: torch.Tensor, reg: torch.Tensor, reg_w: torch.Tensor, scale_weight: float
) -> torch.Tensor:
    """L1 of offset and log sizes at the cells near a centre. Shape: (B, 4, G, G) x2, (B, G, G)."""
    err = (pred - reg).abs()
    per = err[:, 0] + err[:, 1] + scale_weight * err[:, 2] + err[:, 3]
    return (per * reg_w).sum() / reg_w.sum().clamp(min=1)
