"""Point tasks: point navigation with six reward-function tasks, continuous actions (the SAC test bed
of data sharing).

A point in ``[-1, 1]^2`` moves by ``clip(action, -1, 1) * 0.1`` per step (clipped to the box), as in
[`PointReach`][taskrl.envs.point_reach.PointReach]. Observations::

    {"observation": position (2-d float32), "task": int64 index into env.task_set}

The tasks (`POINT_TASKS`): reach one of the four corner regions, the centre region, or the
middle of the right edge, each a box of half-width 0.15. Reward, success and termination are those
of [`taskrl.envs.reward_tasks`][taskrl.envs.reward_tasks]: 1 on entering the task's region, episodes end there or after 40
steps. Episodes start uniformly in the box, outside every region.

The scripted expert flies straight to its region's centre at full speed: what ``expert`` datasets
are made of.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.gymnasium_env import TaskChoiceEnv
from taskrl.envs.reward_tasks import RegionTask, RewardTaskEnv, reward_task_family
from taskrl.types import Obs

HALF = 0.15
MAX_SPEED = 0.1


def _around(x: float, y: float) -> tuple[tuple[float, float], tuple[float, float]]:
    return (x - HALF, y - HALF), (x + HALF, y + HALF)


POINT_TASKS: tuple[RegionTask, ...] = (
    RegionTask("top-left", "Move the point into the top-left corner.", _around(-0.75, 0.75)),
    RegionTask("top-right", "Move the point into the top-right corner.", _around(0.75, 0.75)),
    RegionTask("bottom-left", "Move the point into the bottom-left corner.", _around(-0.75, -0.75)),
    RegionTask("bottom-right", "Move the point into the bottom-right corner.", _around(0.75, -0.75)),
    RegionTask("centre", "Move the point to the centre.", _around(0.0, 0.0)),
    RegionTask("right-edge", "Move the point to the middle of the right edge.", ((0.85, -HALF), (1.0, HALF))),
)


class PointTasks(RewardTaskEnv):
    """``num_envs`` copies of the point tasks, stepped at once in torch.

    Args:
        num_envs: copies stepped in parallel.
        device: torch device of the state.
        tasks: the tasks (default `POINT_TASKS`); boxes in ``[-1, 1]^2``.
        horizon: steps before truncation.
        task_weights: relative share of episodes of each task (imbalance).
        task_sampling: ``uniform`` (drawn by ``task_weights`` every episode) or ``fixed`` (copy i: task i % T).
        seed: seed of the environment's generator.
    """

    def __init__(
        self,
        num_envs: int = 1,
        device: str | torch.device = "cpu",
        tasks=POINT_TASKS,
        horizon: int = 40,
        task_weights=None,
        task_sampling="uniform",
        seed: int | None = None,
    ) -> None:
        self.single_observation_space = gym.spaces.Dict(
            {"observation": gym.spaces.Box(-1.0, 1.0, (2,), np.float32), "task": gym.spaces.Discrete(len(tasks))}
        )
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self._all_targets = torch.tensor([t.target for t in tasks], dtype=torch.float32, device=device)
        super().__init__(tasks, num_envs, device, horizon, task_weights, task_sampling, seed)

    def _start(self, n: int) -> torch.Tensor:
        position = torch.rand((n, 2), generator=self.generator, device=self.device) * 2 - 1
        for _ in range(20):  # redraw the starts inside a region (each round keeps ~85%)
            inside = ((position[:, None] >= self._all_targets[:, 0]) & (position[:, None] <= self._all_targets[:, 1])).all(-1)
            redo = inside.any(-1)
            if not bool(redo.any()):
                break
            position[redo] = torch.rand((int(redo.sum()), 2), generator=self.generator, device=self.device) * 2 - 1
        return position

    def _move(self, position: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        action = action.float().reshape(-1, 2).clamp(-1.0, 1.0)
        return (position + action * MAX_SPEED).clamp_(-1.0, 1.0)

    def _observation(self, position: torch.Tensor) -> torch.Tensor:
        return position.clone()

    def position_of(self, observation: torch.Tensor) -> torch.Tensor:
        return observation.to(self.device).float()

    def expert_action(self, obs: Obs) -> torch.Tensor:
        """Straight to the centre of the task's region at full speed."""
        position = self.position_of(obs["observation"])
        box = self.target[obs["task"].to(self.device).long()]
        return ((box[:, 0] + box[:, 1]) / 2 - position).div(MAX_SPEED).clamp(-1.0, 1.0)


class PointTasksGymEnv(TaskChoiceEnv):
    """Gymnasium view of one copy of `PointTasks` (``taskrl/PointTasks-v0``); ``options={"task": name}`` fixes the task."""

    def __init__(self, render_mode: str | None = None) -> None:
        self._wrap_tasks(PointTasks(num_envs=1, horizon=2**62, seed=0), render_mode)


FAMILY = reward_task_family(
    "pointtasks",
    "point navigation with 6 reward-function tasks (corners, centre, right edge), continuous, native torch",
    PointTasks,
    POINT_TASKS,
    "taskrl/PointTasks-v0",
    "box",
)
