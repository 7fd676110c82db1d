"""Image encoders and the image augmentation of the update.

An image observation reaches a network as the replay stores it, uint8 ``[B, H, W, C]`` (0-255) beside the state
vector ([`ObservationInput`][taskrl.agents.parts.ObservationInput] gives both as a
[`PictureState`][taskrl.agents.parts.PictureState]; no picture is flattened into the vector); `ImageStateInput`
encodes the pictures once per state with a conv stack or a small ResNet, and hands ``[vector, image features]`` on. `random_shift` is DrQ's augmentation: pad by replicating the
border, crop back at a random offset drawn per observation (a scene and its goal picture move together).
"""

from __future__ import annotations

import math
from typing import Any, Literal

import torch
from torch import nn
from torch.nn import functional as F

__all__ = [
    "ENCODERS",
    "FILM_ENCODERS",
    "PICTURE_KEYS",
    "FiLMPictureEncoder",
    "ImageStateInput",
    "conv_stack",
    "random_shift",
    "shift_pictures",
    "stacked_channels",
    "picture_values",
    "small_resnet",
    "SpatialSoftmax",
    "keypoint_stack",
]

ENCODERS = ("conv", "resnet", "keypoints")
#: the encoders `FiLMPictureEncoder` (behaviour cloning) builds
FILM_ENCODERS = ("conv", "resnet")
#: the observation keys that hold pictures, in the order they are stacked for the encoder (the scene, then its goal)
PICTURE_KEYS = ("image", "goal_image")


def _conv(channels: int, out: int, stride: int = 1, orthogonal: bool = True) -> nn.Conv2d:
    """A 3x3 convolution; ``orthogonal``: initialised as DrQ's are (orthogonal weights with ReLU's gain, zero bias),
    else PyTorch's default. The RL encoders use DrQ's: PyTorch's default draws weights with a sixth of the variance
    that He's initialisation keeps a ReLU stack's signal with, and on the grasp bin's pictures (mostly floor) the
    critic's network, taught "would closing here hold an object" directly (``benchmarks/grasp_probe.py``), reached
    AUC 0.74 in 2,000 updates with DrQ's against 0.57 with PyTorch's (both 0.88-0.89 at 6,000). Behaviour cloning
    keeps PyTorch's, the one its results were measured with."""
    conv = nn.Conv2d(channels, out, 3, stride=stride, padding=1)
    if orthogonal:
        nn.init.orthogonal_(conv.weight, nn.init.calculate_gain("relu"))
        nn.init.zeros_(conv.bias)
    return conv


def _conv_blocks(channels: int, orthogonal: bool = True) -> list[nn.Conv2d]:
    return [_conv(channels if i == 0 else 32, 32, 2 if i < 3 else 1, orthogonal) for i in range(4)]


def conv_stack(channels: int, orthogonal: bool = True) -> nn.Sequential:
    """Four 3x3 convolutions of 32 channels (DrQ's depth), the first three of stride 2: a 64x64 picture
    costs about 9 MFLOP (DrQ's single stride-2 layer would cost 50), which CPU training can afford."""
    layers: list[nn.Module] = []
    for conv in _conv_blocks(channels, orthogonal):
        layers += [conv, nn.ReLU()]
    return nn.Sequential(*layers, nn.Flatten())


class _Residual(nn.Module):
    def __init__(self, channels: int, orthogonal: bool) -> None:
        super().__init__()
        conv = [_conv(channels, channels, orthogonal=orthogonal) for _ in range(2)]
        self.body = nn.Sequential(nn.ReLU(), conv[0], nn.ReLU(), conv[1])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


def _resnet_blocks(channels: int, orthogonal: bool = True) -> list[tuple[nn.Module, int]]:
    """``(block, output channels)``: per stage a convolution with its max-pool, then two residual blocks."""
    blocks: list[tuple[nn.Module, int]] = []
    for width in (16, 32):
        stem = nn.Sequential(_conv(channels, width, orthogonal=orthogonal), nn.MaxPool2d(3, stride=2, padding=1))
        blocks += [(stem, width), (_Residual(width, orthogonal), width), (_Residual(width, orthogonal), width)]
        channels = width
    return blocks


def small_resnet(channels: int, orthogonal: bool = True) -> nn.Sequential:
    """A small ResNet (IMPALA's shape): per stage a 3x3 convolution, a 3x3 max-pool of stride 2 and two
    residual blocks; stages of 16 and 32 channels."""
    layers: list[nn.Module] = []
    for block, _ in _resnet_blocks(channels, orthogonal):
        layers += list(block) if isinstance(block, nn.Sequential) else [block]
    return nn.Sequential(*layers, nn.ReLU(), nn.Flatten())


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
        _conv(channels, 16, 2, orthogonal),
        nn.ReLU(),
        _conv(16, 16, 1, orthogonal),
        nn.ReLU(),
        _conv(16, 32, 1, orthogonal),
        SpatialSoftmax((height + 1) // 2, (width + 1) // 2),
    )


def stacked_channels(pictures: torch.Tensor) -> torch.Tensor:
    """``[B, K, H, W, C]`` uint8 pictures -> ``[B, K*C, H, W]`` float, centred (``/ 255 - 0.5``): what the conv
    encoders read. Centred as DrQ's are: a PixelReach run on all-positive inputs that never learnt ended with its
    features nearly constant over states (std 0.009 against 0.45 in one that learnt)."""
    b, k, h, w, c = pictures.shape
    return pictures.permute(0, 1, 4, 2, 3).reshape(b, k * c, h, w) / 255.0 - 0.5


class ImageStateInput(nn.Module):
    """``PictureState(vector [B, V], pictures [B, K, H, W, C] uint8) -> [B, V + features]``: the pictures
    through a conv encoder, a linear layer to ``features``, LayerNorm and tanh (DrQ's head), the vector
    columns unchanged. Several pictures (``image_shape`` ``(K, H, W, C)``: the scene and a goal picture)
    are stacked along the channels and encoded together, so the encoder compares them pixel by pixel.

    Args:
        vector_dim: the state vector's width ``V``.
        image_shape: ``(H, W, C)``, or ``(K, H, W, C)`` for K pictures (the scene and a goal picture).
        kind: ``conv`` (`conv_stack`), ``resnet`` (`small_resnet`) or ``keypoints``
            (`keypoint_stack`: coordinates, which go to the network as they are, without the head).
        features: the image's feature size (``conv`` and ``resnet``).
    """

    def __init__(
        self, vector_dim: int, image_shape: tuple[int, int, int], kind: Literal["conv", "resnet", "keypoints"], features: int
    ) -> None:
        super().__init__()
        self.vector_dim, self.image_shape = int(vector_dim), tuple(int(n) for n in image_shape)
        *_, h, w, c = self.image_shape
        self.pictures = self.image_shape[0] if len(self.image_shape) == 4 else 1
        c = c * self.pictures
        self.trunk = keypoint_stack(c, h, w) if kind == "keypoints" else {"conv": conv_stack, "resnet": small_resnet}[kind](c)
        with torch.no_grad():
            flat = self.trunk(torch.zeros(1, c, h, w)).shape[1]
        # keypoints are bounded coordinates already; a LayerNorm would keep only where they lie relative to each other
        self.head = nn.Identity()
        if kind != "keypoints":
            self.head, flat = nn.Sequential(nn.Linear(flat, features), nn.LayerNorm(features), nn.Tanh()), features
        self.out_dim = self.vector_dim + flat

    def forward(self, state: Any) -> torch.Tensor:
        """``state``: a [`PictureState`][taskrl.agents.parts.PictureState] -> ``[B, V + features]``."""
        return torch.cat([state.vector, self.head(self.trunk(stacked_channels(state.pictures)))], dim=1)


class FiLMPictureEncoder(nn.Module):
    """BC-Z's vision network at CPU scale: ``(pictures [B, H, W, C] uint8, context [B, X]) -> [B, features]``.

    The blocks of `conv_stack` (each convolution) or `small_resnet` (each stage's convolution and
    each residual block), every block's output FiLM-modulated channel by channel by the task's context
    (``(1 + gamma(c)) * h + beta(c)``, identity at initialisation) as BC-Z conditions every ResNet block on the
    task embedding, then DrQ's head (linear to ``features``, LayerNorm, tanh). Without a context
    (``context_dim`` 0) it is the plain encoder.

    Args:
        image_shape: ``(H, W, C)``.
        kind: ``conv`` or ``resnet``.
        features: the output's size.
        context_dim: the context's width (0: no FiLM).
    """

    def __init__(
        self, image_shape: tuple[int, int, int], kind: Literal["conv", "resnet"], features: int, context_dim: int
    ) -> None:
        super().__init__()
        from taskrl.conditioning.film import FiLM

        h, w, c = (int(n) for n in image_shape)
        self.image_shape = (h, w, c)
        if kind == "conv":  # conv -> FiLM -> ReLU
            pairs = [(conv, conv.out_channels) for conv in _conv_blocks(c, orthogonal=False)]
        else:  # stem or residual block -> FiLM; one ReLU at the end, as small_resnet
            pairs = _resnet_blocks(c, orthogonal=False)
        blocks, widths = [b for b, _ in pairs], [w for _, w in pairs]
        self.kind = kind
        self.blocks = nn.ModuleList(blocks)
        self.films = nn.ModuleList(FiLM(context_dim, width) for width in widths) if context_dim > 0 else None
        with torch.no_grad():
            flat = self._trunk(torch.zeros(1, c, h, w), None).shape[1]
        self.head = nn.Sequential(nn.Linear(flat, features), nn.LayerNorm(features), nn.Tanh())
        self.out_dim = int(features)

    def _trunk(self, x: torch.Tensor, context: torch.Tensor | None) -> torch.Tensor:
        for i, block in enumerate(self.blocks):
            x = block(x)
            if self.films is not None and context is not None:
                gamma, beta = self.films[i].scale_shift(context)
                x = gamma[:, :, None, None] * x + beta[:, :, None, None]
            if self.kind == "conv":
                x = torch.relu(x)
        if self.kind == "resnet":
            x = torch.relu(x)
        return x.flatten(1)

    def forward(self, pictures: torch.Tensor, context: torch.Tensor | None = None) -> torch.Tensor:
        # centred, as DrQ's are: from all-positive inputs one BC seed's first layer died (0.7% of its ReLUs alive,
        # 0.15 success after 8k updates); centred, the same seed reached 0.94 at 2k
        x = pictures.permute(0, 3, 1, 2).float() / 255.0 - 0.5
        return self.head(self._trunk(x, context))


def random_shift(images: torch.Tensor, pad: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """DrQ's random shift of ``[B, H, W, C]`` pictures: replicate-pad by ``pad`` and crop back at an offset
    drawn per picture (0 to ``2 * pad`` in each direction). Same dtype and shape as given."""
    if pad <= 0:
        return images
    b, h, w, c = images.shape
    padded = F.pad(images.permute(0, 3, 1, 2).float(), (pad, pad, pad, pad), mode="replicate")  # [B, C, H+2p, W+2p]
    offset = torch.randint(0, 2 * pad + 1, (b, 2), generator=generator, device=images.device)
    rows = (offset[:, 0:1] + torch.arange(h, device=images.device))[:, None, :, None].expand(b, c, h, w + 2 * pad)
    cropped = padded.gather(2, rows)
    cols = (offset[:, 1:2] + torch.arange(w, device=images.device))[:, None, None, :].expand(b, c, h, w)
    return cropped.gather(3, cols).permute(0, 2, 3, 1).to(images.dtype)


def shift_pictures(obs: dict[str, torch.Tensor], pad: int, generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
    """``obs`` with its pictures (`PICTURE_KEYS`) shifted by `random_shift`: one offset per row,
    shared by the row's pictures, since a scene and its goal picture come from one camera and the policy
    reads where the scene differs from the goal (independent offsets would move that difference by up to
    ``2 * pad`` pixels)."""
    keys = [k for k in PICTURE_KEYS if k in obs]
    if not keys:
        return obs
    channels = [obs[k].shape[-1] for k in keys]
    shifted = random_shift(torch.cat([obs[k] for k in keys], dim=-1), pad, generator)
    return {**obs, **dict(zip(keys, shifted.split(channels, dim=-1)))}


def picture_values(shape: tuple[int, ...]) -> int:
    """The values one observation's pictures of ``shape`` hold (``H*W*C``, or ``K*H*W*C``)."""
    return int(math.prod(shape))
