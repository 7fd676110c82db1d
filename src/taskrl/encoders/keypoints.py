"""``keypoints``: convolutions at half resolution, then each channel's expected position (a spatial softmax)."""

from __future__ import annotations

import torch
from torch import nn

from taskrl.encoders.layers import conv3x3
from taskrl.encoders.spec import PictureEncoder

__all__ = ["KEYPOINTS", "SpatialSoftmax", "keypoint_stack"]


class SpatialSoftmax(nn.Module):
    """``[B, C, H, W] -> [B, 2C]``: each channel's expected (x, y) under a softmax over its pixels, in [-1, 1]
    (the keypoints of deep spatial autoencoders and of Levine et al.'s visuomotor policies). A position is read
    to a fraction of a pixel, where a flattened stride-2 stack keeps it only as well as its coarse grid; the
    softmax's temperature is learnt."""

    def __init__(self, height: int, width: int) -> None:
        super().__init__()
        ys, xs = torch.meshgrid(torch.linspace(-1, 1, height), torch.linspace(-1, 1, width), indexing="ij")
        self.register_buffer("grid", torch.stack([xs.reshape(-1), ys.reshape(-1)], 1), persistent=False)  # [H*W, 2]
        self.log_temperature = nn.Parameter(torch.zeros(()))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, h, w = x.shape
        weights = torch.softmax(x.reshape(b * c, h * w) / self.log_temperature.exp(), dim=1)
        return (weights @ self.grid).reshape(b, 2 * c)


def keypoint_stack(channels: int, height: int, width: int, orthogonal: bool = True) -> nn.Sequential:
    """A stride-2 3x3 convolution of 16 channels, two 3x3 convolutions of 16 and 32 at that half resolution, then
    `SpatialSoftmax`: 64 coordinates. A 64x64 picture costs about 15 MFLOP (the conv stack's 9)."""
    return nn.Sequential(
        conv3x3(channels, 16, 2, orthogonal),
        nn.ReLU(),
        conv3x3(16, 16, 1, orthogonal),
        nn.ReLU(),
        conv3x3(16, 32, 1, orthogonal),
        SpatialSoftmax((height + 1) // 2, (width + 1) // 2),
    )


# keypoints are bounded coordinates already; a LayerNorm would keep only where they lie relative to each other
KEYPOINTS = PictureEncoder(
    "keypoints",
    "convolutions at half resolution, then 64 coordinates: each channel's expected position under a softmax",
    trunk=keypoint_stack,
    head=False,
)
