"""Point reaching: a 2-D goal-reaching task with continuous actions, batched in torch.

A point lives in the box ``[-1, 1]^2``. Each step moves it by ``action * max_speed`` (the action
is clipped to ``[-1, 1]^2``) and the position is clipped to the box. Every episode starts at a
uniformly random position with a uniformly random goal. Success is being within
``distance_threshold`` (0.05) of the goal. As in the Fetch tasks, reaching the goal does not end
the episode by default; episodes are truncated at ``horizon`` (50) steps.

Observation (a dict, float32): ``observation`` is the position (2-d; the dynamics are first order,
so the position alone is the Markov state and no velocity is included), ``achieved_goal`` the
position, ``desired_goal`` the goal.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.base import GoalEnvMixin, NativeEnv, Obs, StepResult
from taskrl.envs.spec import EnvFamily, EnvRequest
from taskrl.errors import one_of

RewardType = Literal["sparse", "dense"]
REWARD_TYPES = ("sparse", "dense")


def _check_positive(name: str, value: float) -> None:
    if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def check_point_env_args(num_envs: int, horizon: int, reward: str) -> None:
    """The arguments every point environment shares; a ValueError names the bad one."""
    if not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
    if not isinstance(horizon, int) or horizon < 1:
        raise ValueError(f"horizon must be an integer >= 1, got {horizon!r}")
    if reward not in REWARD_TYPES:
        raise ValueError(f"reward must be one of {', '.join(REWARD_TYPES)}; got {reward!r}")


class PointReach(GoalEnvMixin, NativeEnv):
    """``num_envs`` copies of 2-D point reaching, stepped at once in torch.

    Args:
        num_envs: copies stepped in parallel.
        device: torch device the state lives on.
        horizon: steps before truncation.
        reward: ``"sparse"`` (0 within ``distance_threshold`` of the goal, else -1) or
            ``"dense"`` (minus the distance to the goal).
        max_speed: largest move per step along each axis (the action is scaled by it).
        distance_threshold: success radius around the goal.
        terminate_on_success: end the episode when the goal is reached (default: no, as Fetch).
        seed: seed of the environment's generator.
    """

    def __init__(
        self,
        num_envs: int = 1,
        device: str | torch.device = "cpu",
        horizon: int = 50,
        reward: RewardType = "sparse",
        max_speed: float = 0.1,
        distance_threshold: float = 0.05,
        terminate_on_success: bool = False,
        seed: int | None = None,
    ) -> None:
        check_point_env_args(num_envs, horizon, reward)
        _check_positive("max_speed", max_speed)
        _check_positive("distance_threshold", distance_threshold)
        self.num_envs = num_envs
        self.device = torch.device(device)
        self.horizon = horizon
        self.reward_type: RewardType = reward
        self.max_speed = float(max_speed)
        self.distance_threshold = float(distance_threshold)
        self.terminate_on_success = bool(terminate_on_success)
        box = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.single_observation_space = gym.spaces.Dict({"observation": box, "achieved_goal": box, "desired_goal": box})
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(seed if seed is not None else int(np.random.SeedSequence().entropy % 2**63))
        self.position = torch.zeros(num_envs, 2, dtype=torch.float32, device=self.device)
        self.goal = torch.zeros_like(self.position)
        self.t = torch.zeros(num_envs, dtype=torch.long, device=self.device)

    def _random_points(self, n: int) -> torch.Tensor:
        u = torch.rand((n, 2), generator=self.generator, device=self.device, dtype=torch.float32)
        return (u * 2.0 - 1.0).clamp_(-1.0, 1.0)

    def _reset_where(self, mask: torch.Tensor) -> None:
        n = int(mask.sum())
        if n:
            self.position[mask] = self._random_points(n)
            self.goal[mask] = self._random_points(n)
            self.t[mask] = 0

    def _obs(self) -> Obs:
        position = self.position.clone()
        return {"observation": position, "achieved_goal": position.clone(), "desired_goal": self.goal.clone()}

    def render_rgb(self, index: int = 0):
        """A picture of copy ``index``: the goal (green, its success radius) and the point (blue)."""
        from taskrl.envs.render import draw_points

        goal = (self.goal[index].cpu().numpy(), self.distance_threshold, True)
        return draw_points(self.position[index].cpu().numpy(), [goal])

    def step(self, action: torch.Tensor) -> StepResult:
        action = torch.as_tensor(action, device=self.device, dtype=torch.float32).reshape(self.num_envs, 2)
        self.position = (self.position + action.clamp(-1.0, 1.0) * self.max_speed).clamp_(-1.0, 1.0)
        self.t += 1
        distance = self.distance(self.position, self.goal)
        success = distance <= self.distance_threshold
        reward = self._reward(distance)
        return self._end_step(reward, success)

    @staticmethod
    def distance(achieved_goal: torch.Tensor, desired_goal: torch.Tensor) -> torch.Tensor:
        """Euclidean distance over the last dimension."""
        return torch.linalg.vector_norm(achieved_goal.float() - desired_goal.float(), dim=-1)

    def _reward(self, distance: torch.Tensor) -> torch.Tensor:
        if self.reward_type == "dense":
            return -distance
        return (distance <= self.distance_threshold).float() - 1.0

    def compute_reward(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor, info: Any = None) -> torch.Tensor:
        """Sparse: 0 within ``distance_threshold`` of the goal, else -1. Dense: minus the distance."""
        return self._reward(self.distance(achieved_goal, desired_goal))

    def compute_terminated(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor, info: Any = None) -> torch.Tensor:
        if not self.terminate_on_success:
            return super().compute_terminated(achieved_goal, desired_goal, info)
        return self.distance(achieved_goal, desired_goal) <= self.distance_threshold


@dataclasses.dataclass
class PointReachSettings:
    """Settings of the ``pointreach`` family (and, as its own section, of ``pointreach-mt``).

    Attributes:
        reward: ``sparse`` (0 at the goal, else -1) or ``dense`` (-distance).
        terminate_on_success: end an episode when its goal is reached (default: no, as Fetch).
    """

    reward: Literal["sparse", "dense"] = "sparse"
    terminate_on_success: bool = False

    def validate(self) -> None:
        one_of(self.reward, REWARD_TYPES, "reward", "reward")


def _make_point_reach(settings: PointReachSettings, request: EnvRequest) -> PointReach:
    return PointReach(
        num_envs=request.copies,
        device=request.device,
        reward=settings.reward,
        terminate_on_success=settings.terminate_on_success,
        seed=request.seed,
    )


FAMILY = EnvFamily(
    name="pointreach",
    description="a 2-D point moving to a random goal (continuous actions), native torch",
    section="pointreach",
    settings=PointReachSettings,
    make=_make_point_reach,
    kind="goal",
    actions="box",
    video_env=lambda s: gym.make(
        "taskrl/PointReach-v0", reward=s.reward, terminate_on_success=s.terminate_on_success, render_mode="rgb_array"
    ),
)
