"""Where the pictures meet the networks: `ImageStateInput` (the RL agents: a registered encoder and DrQ's head beside
the state vector) and `FiLMPictureEncoder` (behaviour cloning: every block FiLM-modulated by the task)."""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

from taskrl.encoders.registry import picture_encoder

__all__ = ["FiLMPictureEncoder", "ImageStateInput", "stacked_channels"]


def stacked_channels(pictures: torch.Tensor) -> torch.Tensor:
    """``[B, K, H, W, C]`` uint8 pictures -> ``[B, K*C, H, W]`` float, centred (``/ 255 - 0.5``): what the conv
    encoders read. Centred as DrQ's are: a PixelReach run on all-positive inputs that never learnt ended with its
    features nearly constant over states (std 0.009 against 0.45 in one that learnt)."""
    b, k, h, w, c = pictures.shape
    # as floats before dividing, as the flat input did: dividing the uint8 values themselves rounds some pixels one
    # float32 step apart (the untrained grasp probe's held-out AUC moved in its 7th digit)
    return pictures.float().permute(0, 1, 4, 2, 3).reshape(b, k * c, h, w) / 255.0 - 0.5


class ImageStateInput(nn.Module):
    """``PictureState(vector [B, V], pictures [B, K, H, W, C] uint8) -> [B, V + features]``: the pictures
    through a conv encoder, a linear layer to ``features``, LayerNorm and tanh (DrQ's head), the vector
    columns unchanged. Several pictures (``image_shape`` ``(K, H, W, C)``: the scene and a goal picture)
    are stacked along the channels and encoded together, so the encoder compares them pixel by pixel.

    Args:
        vector_dim: the state vector's width ``V``.
        image_shape: ``(H, W, C)``, or ``(K, H, W, C)`` for K pictures (the scene and a goal picture).
        kind: a registered encoder's name (``conv``, ``resnet``, ``keypoints``: `taskrl.encoders.registry`); one
            without a head (``keypoints``: coordinates) hands its trunk's output on as it is.
        features: the image's feature size (``conv`` and ``resnet``).
    """

    def __init__(self, vector_dim: int, image_shape: tuple[int, int, int], kind: str, features: int) -> None:
        super().__init__()
        self.vector_dim, self.image_shape = int(vector_dim), tuple(int(n) for n in image_shape)
        *_, h, w, c = self.image_shape
        self.pictures = self.image_shape[0] if len(self.image_shape) == 4 else 1
        c = c * self.pictures
        spec = picture_encoder(kind)
        self.trunk = spec.trunk(c, h, w, True)
        with torch.no_grad():
            flat = self.trunk(torch.zeros(1, c, h, w)).shape[1]
        self.head = nn.Identity()
        if spec.head:
            self.head, flat = nn.Sequential(nn.Linear(flat, features), nn.LayerNorm(features), nn.Tanh()), features
        self.out_dim = self.vector_dim + flat

    def forward(self, state: Any) -> torch.Tensor:
        """``state``: a [`PictureState`][taskrl.types.PictureState] -> ``[B, V + features]``."""
        return torch.cat([state.vector, self.head(self.trunk(stacked_channels(state.pictures)))], dim=1)


class FiLMPictureEncoder(nn.Module):
    """BC-Z's vision network at CPU scale: ``(pictures [B, H, W, C] uint8, context [B, X]) -> [B, features]``.

    The blocks of a registered encoder (``film_blocks``: the conv stack's convolutions, the small ResNet's stage
    convolutions and residual blocks), every block's output FiLM-modulated channel by channel by the task's context
    (``(1 + gamma(c)) * h + beta(c)``, identity at initialisation) as BC-Z conditions every ResNet block on the
    task embedding, then DrQ's head (linear to ``features``, LayerNorm, tanh). Without a context
    (``context_dim`` 0) it is the plain encoder.

    Args:
        image_shape: ``(H, W, C)``.
        kind: a registered encoder with ``film_blocks`` (``conv``, ``resnet``).
        features: the output's size.
        context_dim: the context's width (0: no FiLM).
    """

    def __init__(self, image_shape: tuple[int, int, int], kind: str, features: int, context_dim: int) -> None:
        super().__init__()
        from taskrl.conditioning.film import FiLM

        h, w, c = (int(n) for n in image_shape)
        self.image_shape = (h, w, c)
        spec = picture_encoder(kind, film=True)
        pairs = spec.film_blocks(c, False)  # block -> FiLM, then ReLU after each block or once at the end
        blocks, widths = [b for b, _ in pairs], [w for _, w in pairs]
        self.relu_each = spec.film_activation == "each"
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
            if self.relu_each:
                x = torch.relu(x)
        if not self.relu_each:
            x = torch.relu(x)
        return x.flatten(1)

    def forward(self, pictures: torch.Tensor, context: torch.Tensor | None = None) -> torch.Tensor:
        # centred, as DrQ's are: from all-positive inputs one BC seed's first layer died (0.7% of its ReLUs alive,
        # 0.15 success after 8k updates); centred, the same seed reached 0.94 at 2k
        x = pictures.permute(0, 3, 1, 2).float() / 255.0 - 0.5
        return self.head(self._trunk(x, context))
