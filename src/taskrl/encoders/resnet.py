"""``resnet``: a small ResNet (IMPALA's shape), stages of 16 and 32 channels."""

from __future__ import annotations

import torch
from torch import nn

from taskrl.encoders.layers import conv3x3
from taskrl.encoders.spec import PictureEncoder

__all__ = ["RESNET", "resnet_blocks", "small_resnet"]


class _Residual(nn.Module):
    def __init__(self, channels: int, orthogonal: bool) -> None:
        super().__init__()
        conv = [conv3x3(channels, channels, orthogonal=orthogonal) for _ in range(2)]
        self.body = nn.Sequential(nn.ReLU(), conv[0], nn.ReLU(), conv[1])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


def resnet_blocks(channels: int, orthogonal: bool = True) -> list[tuple[nn.Module, int]]:
    """``(block, output channels)``: per stage a convolution with its max-pool, then two residual blocks."""
    blocks: list[tuple[nn.Module, int]] = []
    for width in (16, 32):
        stem = nn.Sequential(conv3x3(channels, width, orthogonal=orthogonal), nn.MaxPool2d(3, stride=2, padding=1))
        blocks += [(stem, width), (_Residual(width, orthogonal), width), (_Residual(width, orthogonal), width)]
        channels = width
    return blocks


def small_resnet(channels: int, orthogonal: bool = True) -> nn.Sequential:
    """A small ResNet (IMPALA's shape): per stage a 3x3 convolution, a 3x3 max-pool of stride 2 and two
    residual blocks; stages of 16 and 32 channels."""
    layers: list[nn.Module] = []
    for block, _ in resnet_blocks(channels, orthogonal):
        layers += list(block) if isinstance(block, nn.Sequential) else [block]
    return nn.Sequential(*layers, nn.ReLU(), nn.Flatten())


def _early_layers(channels: int, orthogonal: bool) -> nn.Module:
    # both stages (H/4, 32 channels): the trunk without its flatten
    return small_resnet(channels, orthogonal)[:-1]


RESNET = PictureEncoder(
    "resnet",
    "a small ResNet (IMPALA's shape): per stage a convolution, a stride-2 max-pool and two residual blocks",
    trunk=lambda channels, height, width, orthogonal: small_resnet(channels, orthogonal),
    film_blocks=resnet_blocks,
    film_activation="end",
    late_input=_early_layers,
)
