"""QT-Opt's Q-network: the action meets the picture inside the conv stack, not after it.

[`StateActionQ`][taskrl.nets.StateActionQ] with an [`ImageStateInput`][taskrl.encoders.ImageStateInput] flattens the picture
to ``image_features`` numbers before the action joins, so the network cannot compare where the gripper will be with
where an object is until both are a handful of numbers. QT-Opt's network (Kalashnikov et al. 2018, Fig. 3) embeds
the action and the gripper's state with a small MLP, tiles the embedding over an intermediate conv feature map, adds
it there, and applies more convolutions. `PictureActionQ` does that at CPU scale:

    h = early(picture)                                   [B, 32, H/8, W/8], three stride-2 3x3 convolutions
    e = MLP([vector, action])                            [B, 32], the action and the state vector embedded
    z = late(relu(h + e tiled over H/8 x W/8))           one stride-2 3x3 convolution to 16 channels
    Q = MLP(flatten(z))

``score_actions`` runs ``early`` once per state and ``late`` once per candidate action: at 64x64 the late part
costs about 0.2 MMAC a candidate (the flat join's MLP: about 0.08), the early part 9 MMAC a state.
"""

from __future__ import annotations

import torch
from torch import nn

from taskrl.encoders.conv import conv_blocks
from taskrl.encoders.layers import conv3x3
from taskrl.encoders.state_input import stacked_channels
from taskrl.nets import mlp
from taskrl.types import PictureState

__all__ = ["FUSIONS", "PictureActionQ"]

#: how the action meets the picture in QT-Opt's Q-network: ``flat`` (after the encoder's features) or ``conv``
FUSIONS = ("flat", "conv")
EMBED = 32  # the early map's channels, and so the action embedding's width
LATE = 16  # channels of the late convolution


class _EarlyPicture(nn.Module):
    """``PictureState(vector [B, V], pictures [B, K, H, W, C]) -> ([B, V], [B, 32, H/8, W/8])``: the pictures' early
    conv map, once per state."""

    def __init__(self, image_shape: tuple[int, ...]) -> None:
        super().__init__()
        self.image_shape = tuple(int(n) for n in image_shape)
        *_, h, w, c = self.image_shape
        self.pictures = self.image_shape[0] if len(self.image_shape) == 4 else 1
        layers: list[nn.Module] = []
        for conv in conv_blocks(c * self.pictures)[:3]:  # the conv stack's three stride-2 layers
            layers += [conv, nn.ReLU()]
        self.convs = nn.Sequential(*layers)

    def forward(self, state: PictureState) -> tuple[torch.Tensor, torch.Tensor]:
        return state.vector, self.convs(stacked_channels(state.pictures))


class PictureActionQ(nn.Module):
    """Q(x, a) with the action added to an intermediate conv feature map (module docstring).

    Args:
        vector_dim: the state vector's width (normalised).
        image_shape: ``(H, W, C)`` (or ``(K, H, W, C)``) of the pictures beside it (uint8 values).
        action_dim: the action's width.
        hidden_sizes: widths of the MLP after the late convolution.
    """

    def __init__(self, vector_dim: int, image_shape: tuple[int, ...], action_dim: int, hidden_sizes: tuple[int, ...]) -> None:
        super().__init__()
        self.state_input = _EarlyPicture(image_shape)  # what a state costs once (CEM reuses it)
        self.embed = nn.Sequential(nn.Linear(vector_dim + action_dim, 64), nn.ReLU(), nn.Linear(64, EMBED))
        self.late = nn.Sequential(conv3x3(EMBED, LATE, 2), nn.ReLU(), nn.Flatten())
        *_, h, w, _ = self.state_input.image_shape
        with torch.no_grad():
            flat = self.late(torch.zeros(1, EMBED, -(-h // 8), -(-w // 8))).shape[1]
        self.head = mlp(flat, hidden_sizes, 1)

    def _q(self, vector: torch.Tensor, early: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        added = torch.relu(early + self.embed(torch.cat([vector, action], -1))[:, :, None, None])
        return self.head(self.late(added)).squeeze(-1)

    def forward(self, x: PictureState, action: torch.Tensor) -> torch.Tensor:
        """x (``B`` states), action [B, A] -> [B]."""
        vector, early = self.state_input(x)
        return self._q(vector, early, action)

    def score_actions(self, x: PictureState, actions: torch.Tensor) -> torch.Tensor:
        """x (``B`` states), actions [B, N, A] -> [B, N]: the early map once per state, the rest once per candidate."""
        b, n, a = actions.shape
        vector, early = self.state_input(x)
        repeat = lambda t: t.repeat_interleave(n, 0)  # noqa: E731
        return self._q(repeat(vector), repeat(early), actions.reshape(b * n, a)).view(b, n)
