"""Single-copy gymnasium views of the native environments, so other libraries can use them.

``gymnasium.make("taskrl/BitFlip-v0", n_bits=15)`` gives a standard ``gymnasium.Env`` with
numpy observations and a numpy ``compute_reward`` that accepts batches (the goal-env API that
hindsight replay buffers of other libraries call).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.bitflip import BitFlip


class BitFlipGymEnv(gym.Env):
    """Gymnasium wrapper around one copy of :class:`BitFlip` (random start and random target).

    Args:
        n_bits: length of the bit string.
        terminate_on_success: end the episode when the target is reached.
    """

    metadata = {"render_modes": []}

    def __init__(self, n_bits: int = 15, terminate_on_success: bool = True) -> None:
        self._env = BitFlip(n_bits, num_envs=1, terminate_on_success=terminate_on_success, seed=0)
        self.observation_space = self._env.single_observation_space
        self.action_space = self._env.single_action_space
        self._obs: dict[str, np.ndarray] | None = None

    @staticmethod
    def _to_numpy(obs: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
        return {k: v[0].numpy().copy() for k, v in obs.items()}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is None:
            seed = int(self.np_random.integers(2**62))
        return self._to_numpy(self._env.reset(seed=seed)), {}

    def step(self, action):
        obs, reward, terminated, truncated, info = self._env.step(torch.as_tensor([int(action)]))
        # Auto-reset belongs to gymnasium's wrappers here: hand back the final observation.
        final = self._to_numpy(info["final_obs"])
        return final, float(reward[0]), bool(terminated[0]), bool(truncated[0]), {"is_success": bool(info["is_success"][0])}

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any = None) -> np.ndarray:
        achieved, desired = np.asarray(achieved_goal), np.asarray(desired_goal)
        return (achieved == desired).all(axis=-1).astype(np.float32) - 1.0


def register_gymnasium_envs() -> None:
    """Register the native environments under the ``taskrl/`` namespace (idempotent)."""
    if "taskrl/BitFlip-v0" not in gym.registry:
        gym.register(id="taskrl/BitFlip-v0", entry_point="taskrl.envs.gymnasium_env:BitFlipGymEnv")
