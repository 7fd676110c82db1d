"""QT-Opt's Q-network: the action meets the picture inside the conv stack, not after it.

[`StateActionQ`][taskrl.nets.StateActionQ] with an [`ImageStateInput`][taskrl.encoders.ImageStateInput] flattens the picture
to ``image_features`` numbers before the action joins, so the network cannot compare where the gripper will be with
where an object is until both are a handful of numbers. QT-Opt's network (Kalashnikov et al. 2018, Fig. 3) embeds
the action and the gripper's state with a small MLP, tiles the embedding over an intermediate conv feature map, adds
it there, and applies more convolutions. `PictureActionQ` does that at CPU scale:

    h = early(picture)                                   [B, E, h, w], the encoder's layers up to its late input
    e = MLP([vector, action])                            [B, E], the action and the state vector embedded
    z = late(relu(h + e tiled over h x w))               one stride-2 3x3 convolution to 16 channels
    Q = MLP(flatten(z))

``early`` is the registered encoder's ``late_input`` (`taskrl.encoders.spec.PictureEncoder`): for ``conv`` its three
stride-2 convolutions (E = 32 at H/8), for ``resnet`` its two stages (E = 32 at H/4).
``score_actions`` runs ``early`` once per state and ``late`` once per candidate action: with ``conv`` at 64x64 the
late part costs about 0.2 MMAC a candidate (the flat join's MLP: about 0.08), the early part 9 MMAC a state.
"""

from __future__ import annotations

import torch
from torch import nn

from taskrl.encoders.layers import conv3x3
from taskrl.encoders.registry import picture_encoder
from taskrl.encoders.state_input import stacked_channels
from taskrl.nets import mlp
from taskrl.types import PictureState

__all__ = ["FUSIONS", "PictureActionQ"]

#: how the action meets the picture in QT-Opt's Q-network: ``flat`` (after the encoder's features), ``conv`` (in an
#: intermediate feature map) or ``glimpse`` (flat, after the features of the whole picture and of the picture around
#: the gripper in the jaws' frame: `taskrl.encoders.GlimpseInput`)
FUSIONS = ("flat", "conv", "glimpse")
LATE = 16  # channels of the late convolution


class _EarlyPicture(nn.Module):
    """``PictureState(vector [B, V], pictures [B, K, H, W, C]) -> ([B, V], [B, E, h, w])``: the pictures' early
    feature map (the encoder's layers up to its late input), once per state."""

    def __init__(self, image_shape: tuple[int, ...], encoder: str) -> None:
        super().__init__()
        self.image_shape = tuple(int(n) for n in image_shape)
        *_, h, w, c = self.image_shape
        self.pictures = self.image_shape[0] if len(self.image_shape) == 4 else 1
        self.convs = picture_encoder(encoder, late_input=True).late_input(c * self.pictures, True)
        with torch.no_grad():  # [E, h, w]: the late input's width and the map it is tiled over
            self.map_shape = tuple(self.convs(torch.zeros(1, c * self.pictures, h, w)).shape[1:])

    def forward(self, state: PictureState) -> tuple[torch.Tensor, torch.Tensor]:
        return state.vector, self.convs(stacked_channels(state.pictures))


class PictureActionQ(nn.Module):
    """Q(x, a) with the action added to an intermediate conv feature map (module docstring).

    Args:
        vector_dim: the state vector's width (normalised).
        image_shape: ``(H, W, C)`` (or ``(K, H, W, C)``) of the pictures beside it (uint8 values).
        action_dim: the action's width.
        hidden_sizes: widths of the MLP after the late convolution.
        encoder: a registered picture encoder that declares a ``late_input`` layer (``conv``, ``resnet``).
    """

    def __init__(
        self,
        vector_dim: int,
        image_shape: tuple[int, ...],
        action_dim: int,
        hidden_sizes: tuple[int, ...],
        encoder: str = "conv",
    ) -> None:
        super().__init__()
        self.state_input = _EarlyPicture(image_shape, encoder)  # what a state costs once (CEM reuses it)
        width = self.state_input.map_shape[0]
        self.embed = nn.Sequential(nn.Linear(vector_dim + action_dim, 64), nn.ReLU(), nn.Linear(64, width))
        self.late = nn.Sequential(conv3x3(width, LATE, 2), nn.ReLU(), nn.Flatten())
        with torch.no_grad():
            flat = self.late(torch.zeros(1, *self.state_input.map_shape)).shape[1]
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
