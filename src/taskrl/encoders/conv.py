"""``conv``: four 3x3 convolutions of 32 channels (DrQ's depth), the first three of stride 2."""

from __future__ import annotations

from torch import nn

from taskrl.encoders.layers import conv3x3
from taskrl.encoders.spec import PictureEncoder

__all__ = ["CONV", "conv_blocks", "conv_stack"]


def conv_blocks(channels: int, orthogonal: bool = True) -> list[nn.Conv2d]:
    """The conv stack's four 3x3 convolutions of 32 channels, the first three of stride 2."""
    return [conv3x3(channels if i == 0 else 32, 32, 2 if i < 3 else 1, orthogonal) for i in range(4)]


def conv_stack(channels: int, orthogonal: bool = True) -> nn.Sequential:
    """Four 3x3 convolutions of 32 channels (DrQ's depth), the first three of stride 2: a 64x64 picture
    costs about 9 MFLOP (DrQ's single stride-2 layer would cost 50), which CPU training can afford."""
    layers: list[nn.Module] = []
    for conv in conv_blocks(channels, orthogonal):
        layers += [conv, nn.ReLU()]
    return nn.Sequential(*layers, nn.Flatten())


def _film_blocks(channels: int, orthogonal: bool) -> list[tuple[nn.Module, int]]:
    return [(conv, conv.out_channels) for conv in conv_blocks(channels, orthogonal)]


def _early_layers(channels: int, orthogonal: bool) -> nn.Module:
    # the three stride-2 layers (H/8): a late input added there costs each candidate action a 1/8-size map
    layers: list[nn.Module] = []
    for conv in conv_blocks(channels, orthogonal)[:3]:
        layers += [conv, nn.ReLU()]
    return nn.Sequential(*layers)


CONV = PictureEncoder(
    "conv",
    "four 3x3 convolutions of 32 channels, three of stride 2 (DrQ's depth at CPU cost)",
    trunk=lambda channels, height, width, orthogonal: conv_stack(channels, orthogonal),
    film_blocks=_film_blocks,
    film_activation="each",
    late_input=_early_layers,
)
