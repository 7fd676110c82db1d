"""Types shared by every layer: an observation batch is a dict of tensors with a leading batch dimension, and the
networks' input of an agent with a camera is a `PictureState`."""

from __future__ import annotations

import dataclasses
from typing import Literal, NamedTuple

import torch

#: A batch of observations by key (``observation``, ``achieved_goal``, ``desired_goal``, ``task``).
Obs = dict[str, torch.Tensor]


class PictureState(NamedTuple):
    """A batch of states as the networks of an agent with a camera read them: the state vector (normalised) and the
    pictures as the replay stores them.

    Attributes:
        vector: ``[B, V]`` float, the vector keys concatenated (``V`` may be 0: pictures only).
        pictures: ``[B, K, H, W, C]`` uint8, the picture keys (``image``, then a goal picture ``goal_image``) stacked; their encoder scales them.
    """

    vector: torch.Tensor
    pictures: torch.Tensor

    @property
    def rows(self) -> int:
        """The batch size ``B``."""
        return self.vector.shape[0]


def state_rows(x: torch.Tensor | PictureState) -> int:
    """The batch size of a networks' input: a tensor ``[B, D]`` or a `PictureState`."""
    return x.rows if isinstance(x, PictureState) else x.shape[0]


@dataclasses.dataclass(frozen=True)
class PictureCoordinate:
    """An entry of a vector observation that is a position in the picture's frame, such as the gripper's x on a bin
    seen from above: ``obs[key][:, index]`` grows by ``per_pixel`` for each pixel the picture's content moves along
    ``axis`` (``row``: down the picture, ``col``: to the right). An env declares these (``picture_coordinates``) so
    that a shift can move them with the picture (`CameraSettings.shift_coordinates`)."""

    key: str
    index: int
    axis: Literal["row", "col"]
    per_pixel: float
