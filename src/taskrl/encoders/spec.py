"""What a picture encoder declares: `PictureEncoder` (each encoder's file declares one)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Literal

from torch import nn

__all__ = ["PictureEncoder"]


@dataclasses.dataclass(frozen=True)
class PictureEncoder:
    """One picture encoder, as the RL agents (SAC, QT-Opt) and behaviour cloning build it.

    Register one with [`register_picture_encoder`][taskrl.encoders.registry.register_picture_encoder]; ``--encoder NAME``
    then uses it.

    Attributes:
        name: the value of ``--encoder``.
        summary: one line for ``--help``.
        trunk: ``(channels, height, width, orthogonal) -> module`` mapping ``[B, channels, H, W]`` float pictures
            (centred, ``/ 255 - 0.5``) to ``[B, F]``; ``orthogonal``: DrQ's initialisation (the RL agents) rather than
            PyTorch's (behaviour cloning).
        head: whether DrQ's head (linear to ``image_features``, LayerNorm, tanh) follows the trunk; False: the trunk's
            ``F`` numbers go on as they are (bounded coordinates, say).
        film_blocks: ``(channels, orthogonal) -> [(block, output channels)]``: the blocks behaviour cloning FiLM-modulates
            one by one (BC-Z conditions every block on the task); None: behaviour cloning refuses this encoder.
        film_activation: where the FiLM encoder applies ReLU: after ``each`` block, or once at the ``end``.
        late_input: ``(channels, orthogonal) -> early``: the layers up to the declared layer where a Q-function adds
            its *late input* (the action and the state vector embedded and tiled over that feature map, as QT-Opt's
            network does; QT-Opt's ``--fusion conv``), mapping ``[B, channels, H, W]`` to ``[B, E, h, w]``, ReLU
            applied; None: this encoder takes no late input.
    """

    name: str
    summary: str
    trunk: Callable[[int, int, int, bool], nn.Module]
    head: bool = True
    film_blocks: Callable[[int, bool], list[tuple[nn.Module, int]]] | None = None
    film_activation: Literal["each", "end"] = "each"
    late_input: Callable[[int, bool], nn.Module] | None = None
