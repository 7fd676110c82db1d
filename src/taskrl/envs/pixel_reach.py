"""Reaching a goal shown as a picture: PointReach seen from above, batched in torch, no OpenGL.

The policy sees two pictures, ``image`` (the scene now) and ``goal_image`` (the scene with the point at
its goal), each ``[size, size, 3]`` uint8: a grey table, the point as a red disc drawn anti-aliased (edge pixels
mixed by coverage, so a move of a fraction of a pixel shows). The state goal stays beside
them (``achieved_goal``, ``desired_goal``: the point's position and its goal, as in PointReach), so the
reward and hindsight relabelling are exact: relabelling replaces ``desired_goal`` by a position the
episode reached and ``goal_image`` by the picture of that moment (``replay/hindsight.py``). The networks
read the pictures, never the state goal (``wiring/parts.py``).

Dynamics, reward and success are PointReach's (``point_reach.py``): a step moves the point by
``action * max_speed`` in ``[-1, 1]^2``; success within 0.05 of the goal; sparse reward by default.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.base import Obs
from taskrl.envs.camera import CameraSettings
from taskrl.envs.gymnasium_env import PointReachGymEnv
from taskrl.envs.point_reach import REWARD_TYPES, PointReach
from taskrl.envs.spec import EnvFamily, EnvRequest
from taskrl.errors import one_of

__all__ = ["FAMILY", "PixelReach", "PixelReachGymEnv", "PixelReachSettings"]

TABLE = (96, 96, 96)
POINT = (230, 40, 40)


class PixelReach(PointReach):
    """``num_envs`` copies of point reaching with goals given as pictures.

    Args:
        image_size: side of both pictures in pixels.
        point_radius: the disc's radius, in units of the ``[-1, 1]`` box.
        **kwargs: [`PointReach`][taskrl.envs.point_reach.PointReach]'s (``num_envs``, ``device``, ``reward``, ...).
    """

    def __init__(self, image_size: int = 32, point_radius: float = 0.12, **kwargs) -> None:
        super().__init__(**kwargs)
        self.image_size, self.point_radius = int(image_size), float(point_radius)
        box = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        picture = gym.spaces.Box(0, 255, (self.image_size, self.image_size, 3), np.uint8)
        self.single_observation_space = gym.spaces.Dict(
            {"image": picture, "goal_image": picture, "achieved_goal": box, "desired_goal": box}
        )
        centres = (torch.arange(self.image_size, device=self.device, dtype=torch.float32) + 0.5) / self.image_size * 2 - 1
        self._rows, self._cols = centres.view(1, -1, 1), centres.view(1, 1, -1)  # y down the picture, x across
        self._table = torch.tensor(TABLE, dtype=torch.float32, device=self.device)
        self._point = torch.tensor(POINT, dtype=torch.float32, device=self.device)

    def picture(self, position: torch.Tensor) -> torch.Tensor:
        """``[B, size, size, 3]`` uint8: the table with the point at each ``position`` (``[B, 2]``, x then y)."""
        x, y = position[:, 0].view(-1, 1, 1), position[:, 1].view(-1, 1, 1)
        distance = ((self._cols - x).square() + (self._rows - y).square()).sqrt()
        # anti-aliased: a pixel's colour mixes by how much of it the disc covers (a linear ramp one pixel wide),
        # so a move well under a pixel (the success radius is 0.8 pixel at 32x32) changes the picture
        pixel = 2.0 / self.image_size
        cover = ((self.point_radius - distance) / pixel + 0.5).clamp(0.0, 1.0)[..., None]
        return (self._table + cover * (self._point - self._table)).round().to(torch.uint8)

    def render_rgb(self, index: int = 0) -> np.ndarray:
        """What the policy of copy ``index`` sees, the scene beside the goal picture, each pixel drawn 4x4."""
        both = torch.cat([self.picture(self.position[index : index + 1]), self.picture(self.goal[index : index + 1])], 2)[0]
        return both.repeat_interleave(4, 0).repeat_interleave(4, 1).cpu().numpy()

    def _obs(self) -> Obs:
        position = self.position.clone()
        return {
            "image": self.picture(position),
            "goal_image": self.picture(self.goal),
            "achieved_goal": position,
            "desired_goal": self.goal.clone(),
        }


class PixelReachGymEnv(PointReachGymEnv):
    """One copy of `PixelReach` as a standard ``gymnasium.Env``, ``taskrl/PixelReach-v0`` (time limit 50).

    Args:
        reward: ``"sparse"`` or ``"dense"``.
        image_size: side of both pictures in pixels.
        render_mode: None or ``rgb_array`` (the scene beside the goal picture).
    """

    def __init__(self, reward: str = "sparse", image_size: int = 32, render_mode: str | None = None) -> None:
        self._wrap(PixelReach(image_size=image_size, num_envs=1, horizon=2**62, reward=reward, seed=0), render_mode)


@dataclasses.dataclass
class PixelReachSettings(CameraSettings):
    """Settings of the ``pixelreach`` family.

    Attributes:
        reward: ``sparse`` (0 at the goal, else -1) or ``dense`` (-distance).
        image_size: side of the scene's and the goal's pictures in pixels.
    """

    reward: Literal["sparse", "dense"] = "sparse"
    image_size: int = 32

    def validate(self) -> None:
        one_of(self.reward, REWARD_TYPES, "reward", "reward")
        super().validate()  # the camera


def _make(settings: PixelReachSettings, request: EnvRequest) -> PixelReach:
    return PixelReach(
        image_size=settings.image_size, num_envs=request.copies, device=request.device, reward=settings.reward, seed=request.seed
    )


FAMILY = EnvFamily(
    name="pixelreach",
    description="PointReach with the scene and the goal as pictures (goal images; hindsight relabels the picture), native torch",
    section="pixelreach",
    settings=PixelReachSettings,
    make=_make,
    kind="goal",
    actions="box",
    images=True,
    video_env=lambda s: gym.make("taskrl/PixelReach-v0", reward=s.reward, image_size=s.image_size, render_mode="rgb_array"),
)
