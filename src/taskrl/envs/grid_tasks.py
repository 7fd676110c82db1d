"""Grid tasks: a 7 x 7 grid world with six reward-function tasks, discrete actions (the DQN test bed of
data sharing).

A walker stands on a cell ``(x, y)`` of a 7 x 7 grid and moves one cell per step: ``0`` stays, ``1`` up,
``2`` down, ``3`` left, ``4`` right (walking into the border stays). Observations::

    {"observation": one-hot of the cell (49-d float32), "task": int64 index into env.task_set}

The tasks (`GRID_TASKS`): reach one of the four corners, reach the centre, and reach the top-left
corner *without stepping on the middle column* (stepping on it ends the episode unsolved). Reward,
success and termination are those of [`taskrl.envs.reward_tasks`][taskrl.envs.reward_tasks]: 1 on reaching the task's cell,
episodes end there, after a hazard, or after 30 steps. Episodes start on a random cell that is no
task's target or hazard.

Why sharing can help here: an episode that walks to one corner passes cells on the way to the others,
so scored under another task's reward it is data for that task too; the avoid task's successes are
successes of ``top-left`` as well, but not the other way round (MT-Opt's example of tasks whose
successes nest).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.gymnasium_env import TaskChoiceEnv
from taskrl.envs.reward_tasks import RegionTask, RewardTaskEnv, reward_task_family
from taskrl.types import Obs

SIZE = 7
GRID_TASKS: tuple[RegionTask, ...] = (
    RegionTask("top-left", "Walk to the top-left corner of the grid.", ((0, 6), (0, 6))),
    RegionTask("top-right", "Walk to the top-right corner of the grid.", ((6, 6), (6, 6))),
    RegionTask("bottom-left", "Walk to the bottom-left corner of the grid.", ((0, 0), (0, 0))),
    RegionTask("bottom-right", "Walk to the bottom-right corner of the grid.", ((6, 0), (6, 0))),
    RegionTask("centre", "Walk to the centre of the grid.", ((3, 3), (3, 3))),
    RegionTask(
        "top-left-avoid",
        "Walk to the top-left corner without stepping on the middle column.",
        ((0, 6), (0, 6)),
        hazard=((3, 1), (3, 5)),
    ),
)
#: (dx, dy) of each action: stay, up, down, left, right
MOVES = torch.tensor([[0, 0], [0, 1], [0, -1], [-1, 0], [1, 0]], dtype=torch.float32)


class GridTasks(RewardTaskEnv):
    """``num_envs`` copies of the grid tasks, stepped at once in torch.

    Args:
        num_envs: copies stepped in parallel.
        device: torch device of the state.
        tasks: the tasks (default `GRID_TASKS`); boxes in cell coordinates ``0 .. 6``.
        horizon: steps before truncation.
        task_weights: relative share of episodes of each task (imbalance).
        task_sampling: ``uniform`` (drawn by ``task_weights`` every episode) or ``fixed`` (copy i: task i % T).
        seed: seed of the environment's generator.
    """

    def __init__(
        self,
        num_envs: int = 1,
        device: str | torch.device = "cpu",
        tasks=GRID_TASKS,
        horizon: int = 30,
        task_weights=None,
        task_sampling="uniform",
        seed: int | None = None,
    ) -> None:
        cells = torch.cartesian_prod(torch.arange(SIZE), torch.arange(SIZE)).float()
        self._moves = MOVES.to(device)
        blocked = torch.zeros(len(cells), dtype=torch.bool)
        for task in tasks:
            for box in (task.target, task.hazard):
                if box is not None:
                    lo, hi = torch.tensor(box[0]), torch.tensor(box[1])
                    blocked |= ((cells >= lo) & (cells <= hi)).all(-1)
        self._starts = cells[~blocked].to(device)
        self.single_observation_space = gym.spaces.Dict(
            {"observation": gym.spaces.Box(0.0, 1.0, (SIZE * SIZE,), np.float32), "task": gym.spaces.Discrete(len(tasks))}
        )
        self.single_action_space = gym.spaces.Discrete(len(MOVES))
        super().__init__(tasks, num_envs, device, horizon, task_weights, task_sampling, seed)

    def _start(self, n: int) -> torch.Tensor:
        pick = torch.randint(len(self._starts), (n,), generator=self.generator, device=self.device)
        return self._starts[pick].clone()

    def _move(self, position: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return (position + self._moves[action.long().reshape(-1)]).clamp_(0, SIZE - 1)

    def _observation(self, position: torch.Tensor) -> torch.Tensor:
        index = (position[:, 0] * SIZE + position[:, 1]).long()
        return torch.nn.functional.one_hot(index, SIZE * SIZE).float()

    def position_of(self, observation: torch.Tensor) -> torch.Tensor:
        index = observation.to(self.device).argmax(-1)
        return torch.stack([index // SIZE, index % SIZE], -1).float()

    def expert_action(self, obs: Obs) -> torch.Tensor:
        """Shortest-path walking: along x towards the target, unless that steps on the task's
        hazard (then along y); along y once x is right."""
        position = self.position_of(obs["observation"])
        task = obs["task"].to(self.device).long()
        goal = self.target[task, 0]
        dx, dy = (goal - position).sign().unbind(-1)
        along_x = torch.where(dx > 0, 4, 3)
        along_y = torch.where(dy > 0, 1, 2)
        stepped = self._move(position, along_x)
        blocked = self._inside(self.hazard, stepped, task)
        action = torch.where((dx != 0) & ~blocked, along_x, torch.where(dy != 0, along_y, 0))
        # x blocked by the hazard and y already right: step away from the hazard's rows
        return torch.where((dx != 0) & blocked & (dy == 0), torch.where(position[:, 1] >= 3, 1, 2), action)

    def _unit(self, position: torch.Tensor) -> torch.Tensor:
        return position / (SIZE - 1) * 2 - 1


class GridTasksGymEnv(TaskChoiceEnv):
    """Gymnasium view of one copy of `GridTasks` (``taskrl/GridTasks-v0``); ``options={"task": name}`` fixes the task."""

    def __init__(self, render_mode: str | None = None) -> None:
        self._wrap_tasks(GridTasks(num_envs=1, horizon=2**62, seed=0), render_mode)


FAMILY = reward_task_family(
    "gridtasks",
    "a 7x7 grid world with 6 reward-function tasks (corners, centre, one with a hazard), discrete, native torch",
    GridTasks,
    GRID_TASKS,
    "taskrl/GridTasks-v0",
    "discrete",
)
