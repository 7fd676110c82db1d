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


@dataclasses.dataclass(frozen=True)
class PicturePose:
    """Where a gripper seen from above is in the picture and how its jaws are turned, as columns of a vector
    observation: ``obs[key][:, x]`` and ``obs[key][:, y]`` its position as fractions of the picture's width and height
    (a pixel's centre at ``(column + 0.5) / width``, ``(row + 0.5) / height``), ``obs[key][:, cos]`` and
    ``obs[key][:, sin]`` the cosine and sine of ``turns`` times its yaw (the angle from the picture's columns axis
    towards its rows axis of the line the jaws close along; ``turns`` 2 where jaws turned by pi are the same jaws).

    An env declares it (``picture_pose``) so that a network can look at the picture around the gripper in the jaws'
    frame (`taskrl.encoders.GlimpseInput`, QT-Opt's ``fusion=glimpse``); the agent is given it with the columns
    counted in its state vector (`in_vector`)."""

    key: str
    x: int
    y: int
    cos: int
    sin: int
    turns: int = 1

    @property
    def columns(self) -> tuple[int, int, int, int]:
        """``(x, y, cos, sin)``."""
        return (self.x, self.y, self.cos, self.sin)

    def in_vector(self, offset: int) -> PicturePose:
        """The same pose with its columns counted from ``offset`` (where ``key`` starts in a concatenated vector)."""
        return dataclasses.replace(self, x=self.x + offset, y=self.y + offset, cos=self.cos + offset, sin=self.sin + offset)
