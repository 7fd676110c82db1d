"""Bit flipping, the task of the hindsight experience replay paper (Andrychowicz et al., 2017).

Every episode starts from a random bit string and has a random target string. An action flips
one bit; the reward is 0 when the state equals the target and -1 otherwise. Without hindsight
relabelling the reward is almost never 0 for large ``n_bits``, which is why plain DQN fails
beyond about 13 bits.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.base import GoalEnvMixin, NativeEnv, Obs, StepResult
from taskrl.envs.spec import EnvFamily, EnvRequest
from taskrl.errors import require


class BitFlip(GoalEnvMixin, NativeEnv):
    """``num_envs`` copies of ``n_bits``-bit flipping, stepped at once in torch.

    Args:
        n_bits: length of the bit string (>= 1); also the number of actions.
        num_envs: copies stepped in parallel.
        device: torch device the state lives on.
        horizon: steps before truncation (default ``n_bits``, as in the paper).
        terminate_on_success: end the episode when the target is reached. Relabelled
            transitions then recompute termination through ``compute_terminated``.
        seed: seed of the environment's generator.
    """

    def __init__(
        self,
        n_bits: int,
        num_envs: int = 1,
        device: str | torch.device = "cpu",
        horizon: int | None = None,
        terminate_on_success: bool = True,
        seed: int | None = None,
    ) -> None:
        if n_bits < 1:
            raise ValueError(f"n_bits must be >= 1, got {n_bits}")
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.n_bits = n_bits
        self.num_envs = num_envs
        self.device = torch.device(device)
        self.horizon = horizon if horizon is not None else n_bits
        if self.horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {self.horizon}")
        self.terminate_on_success = terminate_on_success
        bits = gym.spaces.MultiBinary(n_bits)
        self.single_observation_space = gym.spaces.Dict({"observation": bits, "achieved_goal": bits, "desired_goal": bits})
        self.single_action_space = gym.spaces.Discrete(n_bits)
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(seed if seed is not None else int(np.random.SeedSequence().entropy % 2**63))
        self.state = torch.zeros(num_envs, n_bits, dtype=torch.int8, device=self.device)
        self.goal = torch.zeros_like(self.state)
        self.t = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self._arange = torch.arange(num_envs, device=self.device)

    def _random_bits(self, n: int) -> torch.Tensor:
        return torch.randint(0, 2, (n, self.n_bits), generator=self.generator, device=self.device, dtype=torch.int8)

    def _reset_where(self, mask: torch.Tensor) -> None:
        n = int(mask.sum())
        if n:
            self.state[mask] = self._random_bits(n)
            self.goal[mask] = self._random_bits(n)
            self.t[mask] = 0

    def _obs(self) -> Obs:
        state = self.state.clone()
        return {"observation": state, "achieved_goal": state, "desired_goal": self.goal.clone()}

    def render_rgb(self, index: int = 0):
        """A picture of copy ``index``: its bits (top row) and its target (bottom row)."""
        from taskrl.envs.render import draw_bits

        return draw_bits(self.state[index].cpu().numpy(), self.goal[index].cpu().numpy())

    def step(self, action: torch.Tensor) -> StepResult:
        action = torch.as_tensor(action, device=self.device).long().reshape(self.num_envs)
        self.state[self._arange, action] ^= 1
        self.t += 1
        success = (self.state == self.goal).all(dim=1)
        reward = self.compute_reward(self.state, self.goal)
        return self._end_step(reward, success)

    def compute_reward(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor, info: Any = None) -> torch.Tensor:
        """0 where ``achieved_goal == desired_goal`` (all bits), else -1."""
        return (achieved_goal == desired_goal).all(dim=-1).float() - 1.0

    def compute_terminated(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor, info: Any = None) -> torch.Tensor:
        if not self.terminate_on_success:
            return super().compute_terminated(achieved_goal, desired_goal, info)
        return (achieved_goal == desired_goal).all(dim=-1)


@dataclasses.dataclass
class BitFlipSettings:
    """Settings of the ``bitflip`` family.

    Attributes:
        n_bits: bit-string length (also the number of actions and the horizon).
        terminate_on_success: end an episode when its target is reached.
    """

    n_bits: int = 15
    terminate_on_success: bool = True

    def validate(self) -> None:
        require(self.n_bits >= 1, "n_bits", f"must be >= 1 (got {self.n_bits})")


def _make_bitflip(settings: BitFlipSettings, request: EnvRequest) -> BitFlip:
    return BitFlip(
        settings.n_bits,
        num_envs=request.copies,
        device=request.device,
        terminate_on_success=settings.terminate_on_success,
        seed=request.seed,
    )


FAMILY = EnvFamily(
    name="bitflip",
    description="bit flipping with a random start and target (the hindsight paper's task), native torch",
    section="bitflip",
    settings=BitFlipSettings,
    make=_make_bitflip,
    kind="goal",
    actions="discrete",
    video_env=lambda s: gym.make(
        "taskrl/BitFlip-v0", n_bits=s.n_bits, terminate_on_success=s.terminate_on_success, render_mode="rgb_array"
    ),
)
