"""Pushing a block to a goal shown as a picture: the tabletop's pusher and one block, batched in torch.

The goal-image task with an object to move (where [`pixel_reach`][taskrl.envs.pixel_reach] moves the agent itself):
the policy sees ``image`` (the table now) and ``goal_image`` (the table with the block where it should
be, and no pusher), each ``[size, size, 3]`` uint8 drawn by the tabletop's camera
([`draw_table`][taskrl.envs.tabletop.draw_table]), and the pusher's own position (``observation``, as a robot knows
its arm's pose). Where the block is and where it should go are only in the pictures. The state goal stays
beside them (``achieved_goal``: the block's centre; ``desired_goal``: its goal), so the reward and hindsight
relabelling are exact: relabelling replaces ``desired_goal`` by where the block was later in the episode and
``goal_image`` by `PixelPush.goal_picture` of it (``replay/hindsight.py``), so the env's goals and hindsight's
are pictures of one kind: the block alone. (Hindsight once used the picture of that moment, the pusher usually
beside the block, while the env's goals put the pusher at a random spot: two distributions.) The networks read
the pictures, never the state goal (``wiring/parts.py``).

``observation="state"`` is the same task without pictures (``observation`` = pusher and block positions; the
goal as ``desired_goal``): the control that prices the pixels.

Dynamics are the tabletop's ([`shove`][taskrl.envs.tabletop.shove]): the pusher moves by ``action * 0.1`` and
shoves the block out of its way. The block starts in ``[-0.5, 0.5]^2``, its goal 0.2 to 0.5 away, the pusher
anywhere on the table. Success: the block's centre within ``distance_threshold`` (0.1, 1.6 pixels at 32x32)
of the goal; sparse reward (0 there, else -1) by default; episodes of ``horizon`` steps, as FetchPush's.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.base import Obs, StepResult
from taskrl.envs.camera import CameraSettings
from taskrl.envs.gymnasium_env import PointReachGymEnv
from taskrl.envs.point_reach import REWARD_TYPES, PointReach
from taskrl.envs.spec import EnvFamily, EnvRequest
from taskrl.envs.tabletop import COLOURS, draw_table, move_pusher, shove
from taskrl.errors import one_of, require

__all__ = ["FAMILY", "PixelPush", "PixelPushGymEnv", "PixelPushSettings"]

OBSERVATIONS = ("pixels", "state")
OFF_TABLE = 10.0  # a pusher drawn here covers no pixel


class PixelPush(PointReach):
    """``num_envs`` copies of block pushing with goals given as pictures (see the module docstring).

    Args:
        image_size: side of both pictures in pixels.
        observation: ``pixels`` (pictures and the pusher's position) or ``state`` (pusher and block positions).
        distance_threshold: success radius of the block around its goal.
        **kwargs: [`PointReach`][taskrl.envs.point_reach.PointReach]'s (``num_envs``, ``device``, ``horizon``, ``reward``,
            ``seed``).
    """

    def __init__(
        self,
        image_size: int = 32,
        observation: Literal["pixels", "state"] = "pixels",
        distance_threshold: float = 0.1,
        **kwargs,
    ) -> None:
        super().__init__(distance_threshold=distance_threshold, **kwargs)
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {', '.join(OBSERVATIONS)}; got {observation!r}")
        self.image_size, self.pictures = int(image_size), observation == "pixels"
        box = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        if self.pictures:
            picture = gym.spaces.Box(0, 255, (self.image_size, self.image_size, 3), np.uint8)
            spaces = {"observation": box, "image": picture, "goal_image": picture}
        else:
            spaces = {"observation": gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)}
        self.single_observation_space = gym.spaces.Dict({**spaces, "achieved_goal": box, "desired_goal": box})
        self.block = torch.zeros_like(self.position)  # ``position`` is the pusher's; ``goal`` the block's goal
        self._colour = torch.tensor([COLOURS["red"]], dtype=torch.float32, device=self.device)

    def _uniform(self, n: int, low: float, high: float) -> torch.Tensor:
        return low + (high - low) * torch.rand(n, generator=self.generator, device=self.device)

    def _reset_where(self, mask: torch.Tensor) -> None:
        n = int(mask.sum())
        if not n:
            return
        block = torch.stack([self._uniform(n, -0.5, 0.5), self._uniform(n, -0.5, 0.5)], 1)
        turn, reach = self._uniform(n, 0.0, 2 * math.pi), self._uniform(n, 0.2, 0.5)
        goal = (block + reach[:, None] * torch.stack([torch.cos(turn), torch.sin(turn)], 1)).clamp(-0.7, 0.7)
        pusher = move_pusher(
            torch.stack([self._uniform(n, -0.9, 0.9), self._uniform(n, -0.9, 0.9)], 1), torch.zeros(n, 2, device=self.device)
        )
        self.position[mask] = pusher
        self.block[mask] = shove(pusher, block[:, None])[:, 0]  # a pusher dropped onto the block shoves it aside
        self.goal[mask] = goal
        self.t[mask] = 0

    def picture(self, block: torch.Tensor, pusher: torch.Tensor) -> torch.Tensor:
        """``[B, size, size, 3]`` uint8: the table with the block at ``block`` and the pusher at ``pusher``."""
        return draw_table(block[:, None], self._colour, pusher, self.image_size)

    def goal_picture(self, goal: torch.Tensor) -> torch.Tensor:
        """``[B, size, size, 3]`` uint8: the table with the block at ``goal`` and no pusher (the pusher is drawn off
        the table): the env's goal pictures and hindsight's relabelled ones alike."""
        return self.picture(goal, torch.full_like(goal, OFF_TABLE))

    def _obs(self) -> Obs:
        pusher, block = self.position.clone(), self.block.clone()
        goals = {"achieved_goal": block, "desired_goal": self.goal.clone()}
        if not self.pictures:
            return {"observation": torch.cat([pusher, block], 1), **goals}
        return {
            "observation": pusher,
            "image": self.picture(block, pusher),
            "goal_image": self.goal_picture(self.goal),
            **goals,
        }

    def step(self, action: torch.Tensor) -> StepResult:
        action = torch.as_tensor(action, device=self.device, dtype=torch.float32).reshape(self.num_envs, 2)
        self.position = move_pusher(self.position, action)
        self.block = shove(self.position, self.block[:, None])[:, 0]
        self.t += 1
        distance = self.distance(self.block, self.goal)
        return self._end_step(self._reward(distance), distance <= self.distance_threshold)

    def render_rgb(self, index: int = 0) -> np.ndarray:
        """Copy ``index``'s scene beside its goal picture, each pixel drawn 4x4."""
        i = slice(index, index + 1)
        both = torch.cat([self.picture(self.block[i], self.position[i]), self.goal_picture(self.goal[i])], 2)[0]
        return both.repeat_interleave(4, 0).repeat_interleave(4, 1).cpu().numpy()


class PixelPushGymEnv(PointReachGymEnv):
    """One copy of `PixelPush` as a standard ``gymnasium.Env``, ``taskrl/PixelPush-v0`` (time limit 50).

    Args:
        reward: ``"sparse"`` or ``"dense"``.
        image_size: side of both pictures in pixels.
        observation: ``pixels`` or ``state``.
        render_mode: None or ``rgb_array`` (the scene beside the goal picture).
    """

    def __init__(
        self, reward: str = "sparse", image_size: int = 32, observation: str = "pixels", render_mode: str | None = None
    ) -> None:
        env = PixelPush(image_size=image_size, observation=observation, num_envs=1, horizon=2**62, reward=reward, seed=0)
        self._wrap(env, render_mode)


@dataclasses.dataclass
class PixelPushSettings(CameraSettings):
    """Settings of the ``pixelpush`` family.

    Attributes:
        reward: ``sparse`` (0 with the block at its goal, else -1) or ``dense`` (-distance of the block to it).
        image_size: side of the scene's and the goal's pictures in pixels.
        observation: ``pixels`` (the two pictures and the pusher's position) or ``state`` (pusher and block
            positions, the goal as a vector: the control without pictures).
        horizon: steps of an episode.
    """

    reward: Literal["sparse", "dense"] = "sparse"
    image_size: int = 32
    observation: Literal["pixels", "state"] = "pixels"
    horizon: int = 50

    def validate(self) -> None:
        one_of(self.reward, REWARD_TYPES, "reward", "reward")
        one_of(self.observation, OBSERVATIONS, "observation", "observation")
        super().validate()  # the camera
        require(self.horizon >= 1, "horizon", f"must be >= 1 (got {self.horizon})")


def _make(settings: PixelPushSettings, request: EnvRequest) -> PixelPush:
    return PixelPush(
        image_size=settings.image_size,
        observation=settings.observation,
        num_envs=request.copies,
        device=request.device,
        horizon=settings.horizon,
        reward=settings.reward,
        seed=request.seed,
    )


FAMILY = EnvFamily(
    name="pixelpush",
    description="push a block to a goal shown as a picture (the tabletop's pusher; hindsight relabels the picture), "
    "native torch; observation=state is the control without pictures",
    section="pixelpush",
    settings=PixelPushSettings,
    make=_make,
    kind="goal",
    actions="box",
    images=True,
    video_env=lambda s: gym.make(
        "taskrl/PixelPush-v0", reward=s.reward, image_size=s.image_size, observation=s.observation, render_mode="rgb_array"
    ),
)
