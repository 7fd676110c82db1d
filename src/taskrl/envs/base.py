"""The batched environment contract every native environment follows.

A batched environment steps ``num_envs`` copies at once. Everything is a tensor with a leading
env dimension, on ``device``. Episodes reset automatically in the same step they end: the
returned observation is the first one of the new episode and ``info["final_obs"]`` holds the
observation the finished episode ended in (for every env; it equals ``obs`` where nothing ended).
That is the only place final observations appear, so a collector reads the true next state as
``info["final_obs"]``.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import torch

from taskrl.types import Obs

StepResult = tuple[Obs, torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]


class BatchedEnv:
    """Base class of native batched environments.

    Subclasses set ``num_envs``, ``device``, ``horizon`` (maximum episode length; None for an env
    that ends its own episodes and declares no limit), ``single_observation_space`` (a gymnasium ``Dict``) and ``single_action_space``, and implement
    ``reset`` and ``step``.
    """

    num_envs: int
    device: torch.device
    horizon: int | None
    single_observation_space: gym.spaces.Dict
    single_action_space: gym.spaces.Space

    def reset(self, seed: int | None = None) -> Obs:
        """Reset every copy. ``seed`` reseeds the environment's generator."""
        raise NotImplementedError

    def step(self, action: torch.Tensor) -> StepResult:
        """Advance every copy by one step; returns ``obs, reward, terminated, truncated, info``."""
        raise NotImplementedError

    def close(self) -> None:
        """Release what the environment holds (worker processes of gymnasium vector envs)."""


class NativeEnv(BatchedEnv):
    """A batched environment written in torch: the one place native environments end episodes.

    Subclasses keep a step counter ``t`` (``[num_envs]``), a ``generator``, a
    ``terminate_on_success`` flag, and implement ``_obs()`` (the current observation) and
    ``_reset_where(mask)`` (new episodes in the masked copies); their ``step`` advances the state and
    returns ``self._end_step(reward, success)``.

    ``horizon_is_terminal``: an env whose observation carries the time left sets it, so running out of
    steps ends the episode in a terminal state (value 0) rather than a cut-off one to bootstrap from.
    """

    t: torch.Tensor
    generator: torch.Generator
    terminate_on_success: bool
    horizon_is_terminal: bool = False

    def _obs(self) -> Obs:
        raise NotImplementedError

    def _reset_where(self, mask: torch.Tensor) -> None:
        raise NotImplementedError

    def reset(self, seed: int | None = None) -> Obs:
        if seed is not None:
            self.generator.manual_seed(seed)
        self._reset_where(torch.ones(self.num_envs, dtype=torch.bool, device=self.device))
        return self._obs()

    def _end_step(self, reward: torch.Tensor, success: torch.Tensor, failed: torch.Tensor | None = None) -> StepResult:
        """Termination on success (if enabled) or on ``failed`` (a hazard touched), truncation at
        ``horizon`` (termination where ``horizon_is_terminal``), same-step reset of the copies that ended,
        and their final observation in ``info["final_obs"]``."""
        terminated = success if self.terminate_on_success else torch.zeros_like(success)
        if failed is not None:
            terminated = terminated | failed
        out_of_time = self.t >= self.horizon
        if self.horizon_is_terminal:
            terminated = terminated | out_of_time
        truncated = out_of_time & ~terminated
        final_obs = self._obs()
        self._reset_where(terminated | truncated)
        info: dict[str, Any] = {"is_success": success, "final_obs": final_obs}
        return self._obs(), reward, terminated, truncated, info


class GoalEnvMixin:
    """Goal-conditioned environments: observations carry ``achieved_goal`` and ``desired_goal``.

    ``compute_reward`` and ``compute_terminated`` take batches of goals and follow the signature
    gymnasium-robotics uses, so hindsight relabelling treats native and gymnasium environments
    alike.
    """

    def compute_reward(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor, info: Any = None) -> torch.Tensor:
        raise NotImplementedError

    def compute_terminated(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor, info: Any = None) -> torch.Tensor:
        """Whether reaching ``achieved_goal`` ends the episode for ``desired_goal`` (default: never)."""
        return torch.zeros(achieved_goal.shape[0], dtype=torch.bool, device=achieved_goal.device)


def is_goal_env(env: Any) -> bool:
    """True when ``env`` exposes the goal-env observation keys and a ``compute_reward``."""
    space = getattr(env, "single_observation_space", None)
    keys = set(space.spaces) if isinstance(space, gym.spaces.Dict) else set()
    return {"achieved_goal", "desired_goal"} <= keys and callable(getattr(env, "compute_reward", None))
