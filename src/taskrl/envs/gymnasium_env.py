"""Single-copy gymnasium views of the native environments, so other libraries can use them.

``gymnasium.make("taskrl/BitFlip-v0", n_bits=15)`` (or ``"taskrl/PointReach-v0"``) gives a
standard ``gymnasium.Env`` with numpy observations and a numpy ``compute_reward`` that accepts
batches (the goal-env API that hindsight replay buffers of other libraries call).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.bitflip import BitFlip
from taskrl.envs.point_reach import PointReach, RewardType
from taskrl.registration import register_gymnasium_envs

__all__ = ["BitFlipGymEnv", "PointReachGymEnv", "SingleCopyEnv", "TaskChoiceEnv", "register_gymnasium_envs"]


class SingleCopyEnv(gym.Env):
    """One copy of a native batched environment as a standard ``gymnasium.Env`` with numpy data.

    Subclasses build the copy (``num_envs=1``) and pass it to `_wrap`. Auto-reset belongs
    to gymnasium's wrappers here, so ``step`` returns the observation an episode ended in.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}
    render_mode: str | None = None

    def _wrap(self, env: Any, render_mode: str | None = None) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self._env, self.render_mode = env, render_mode
        self.observation_space = env.single_observation_space
        self.action_space = env.single_action_space

    def render(self):
        """An RGB picture of the copy (``render_mode="rgb_array"``)."""
        return self._env.render_rgb(0) if self.render_mode == "rgb_array" else None

    @staticmethod
    def _to_numpy(obs: dict[str, torch.Tensor]) -> dict[str, Any]:
        return {k: v[0].cpu().numpy().copy() for k, v in obs.items()}

    def _action(self, action: Any) -> torch.Tensor:
        if isinstance(self.action_space, gym.spaces.Discrete):
            return torch.as_tensor([int(action)])
        return torch.as_tensor(np.asarray(action, dtype=np.float32).reshape(1, -1))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        return self._to_numpy(self._env.reset(seed=int(self.np_random.integers(2**62)))), {}

    def step(self, action):
        obs, reward, terminated, truncated, info = self._env.step(self._action(action))
        final = self._to_numpy(info["final_obs"])
        return final, float(reward[0]), bool(terminated[0]), bool(truncated[0]), {"is_success": bool(info["is_success"][0])}


class TaskChoiceEnv(SingleCopyEnv):
    """One copy of a native multi-task environment (observations ``observation`` and ``task``): the task
    is drawn at every reset, or fixed by ``options={"task": i}`` (an index or a task name).

    Subclasses pass the copy to `_wrap_tasks`; it must have a ``task_set`` and a ``task`` tensor.
    """

    def _wrap_tasks(self, env: Any, render_mode: str | None = None) -> None:
        self._wrap(env, render_mode)
        self.task_set = env.task_set

    @staticmethod
    def _to_numpy(obs: dict[str, torch.Tensor]) -> dict[str, Any]:
        return {k: np.int64(v[0].item()) if k == "task" else v[0].cpu().numpy().copy() for k, v in obs.items()}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = super().reset(seed=seed)
        task = (options or {}).get("task")
        if task is not None:
            index = self.task_set.index(task) if isinstance(task, str) else int(task)
            if not 0 <= index < len(self.task_set):
                raise ValueError(
                    f"options['task'] must be in 0..{len(self.task_set) - 1} or one of {self.task_set.names}; got {task!r}"
                )
            self._env.task[0] = index
            obs = self._to_numpy(self._env._obs())
        return obs, info


class BitFlipGymEnv(SingleCopyEnv):
    """Gymnasium wrapper around one copy of `BitFlip` (random start and random target).

    Args:
        n_bits: length of the bit string.
        terminate_on_success: end the episode when the target is reached.
    """

    def __init__(self, n_bits: int = 15, terminate_on_success: bool = True, render_mode: str | None = None) -> None:
        self._wrap(BitFlip(n_bits, num_envs=1, terminate_on_success=terminate_on_success, seed=0), render_mode)

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any = None) -> np.ndarray:
        achieved, desired = np.asarray(achieved_goal), np.asarray(desired_goal)
        return (achieved == desired).all(axis=-1).astype(np.float32) - 1.0


class PointReachGymEnv(SingleCopyEnv):
    """Gymnasium wrapper around one copy of `PointReach` (random start and random goal).

    The episode length is gymnasium's time limit (``max_episode_steps``, registered as 50, the
    native default); the wrapped copy never truncates by itself.

    Args:
        reward: ``"sparse"`` or ``"dense"`` (see `PointReach`).
        max_speed: largest move per step along each axis.
        distance_threshold: success radius around the goal.
        terminate_on_success: end the episode when the goal is reached.
    """

    def __init__(
        self,
        reward: RewardType = "sparse",
        max_speed: float = 0.1,
        distance_threshold: float = 0.05,
        terminate_on_success: bool = False,
        render_mode: str | None = None,
    ) -> None:
        self._wrap(
            PointReach(
                num_envs=1,
                horizon=2**62,
                reward=reward,
                max_speed=max_speed,
                distance_threshold=distance_threshold,
                terminate_on_success=terminate_on_success,
                seed=0,
            ),
            render_mode,
        )

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any = None) -> np.ndarray:
        """Vectorised over leading dimensions, like gymnasium-robotics' goal envs."""
        diff = np.asarray(achieved_goal, dtype=np.float32) - np.asarray(desired_goal, dtype=np.float32)
        distance = np.linalg.norm(diff, axis=-1)
        if self._env.reward_type == "dense":
            return (-distance).astype(np.float32)
        return (distance <= self._env.distance_threshold).astype(np.float32) - 1.0

    def compute_terminated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any = None) -> np.ndarray:
        diff = np.asarray(achieved_goal, dtype=np.float32) - np.asarray(desired_goal, dtype=np.float32)
        reached = np.linalg.norm(diff, axis=-1) <= self._env.distance_threshold
        return reached if self._env.terminate_on_success else np.zeros_like(reached)
