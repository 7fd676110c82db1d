"""Multi-task worlds whose tasks are known reward functions: the test beds of data sharing.

Every task ``j`` is a named, described reward function ``r_j(s, a, s')`` with a success test, so any
stored transition can be scored under any task (MT-Opt's task impersonation, HIPI, CDS)::

    success_j(s')  = s' lies in task j's target region
    failure_j(s')  = s' lies in task j's hazard region (tasks "... without touching ...")
    r_j(s, a, s')  = 1 if success_j(s') else 0                      (MT-Opt's binary success reward)
    terminated_j   = success_j(s') or failure_j(s')

Rewards are 0 / 1, so 0 is the lowest reward: what data sharing with zero rewards (UDS) assumes of
unlabeled data. An episode ends at its task's success or failure, or after ``horizon`` steps.

Two families use this base: [`taskrl.envs.grid_tasks`][taskrl.envs.grid_tasks] (a grid world, discrete actions, for
DQN) and [`taskrl.envs.point_tasks`][taskrl.envs.point_tasks] (point navigation, continuous actions, for SAC). Each
also has a scripted expert (``expert_action``), from which the offline datasets of
[`taskrl.sharing.datasets`][taskrl.sharing.datasets] are made.

Imbalance, as in MT-Opt: ``task_weights`` sets the share of training episodes each task gets
(``--low-data-tasks A,B --low-data-fraction 0.1`` gives A and B a tenth of the others' weight).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.base import NativeEnv, Obs, StepResult
from taskrl.envs.spec import DemoSource, EnvFamily, EnvRequest
from taskrl.errors import ConfigError, require
from taskrl.tasks import TaskSet

__all__ = [
    "RegionTask",
    "RewardTaskEnv",
    "reward_task_family",
    "RewardTaskSettings",
    "QUALITIES",
    "parse_qualities",
    "task_weights",
]

Box = tuple[tuple[float, float], tuple[float, float]]  # ((x_lo, y_lo), (x_hi, y_hi)), inclusive
QUALITIES = ("expert", "medium", "random")


@dataclasses.dataclass(frozen=True)
class RegionTask:
    """One task: reach ``target``; with a ``hazard``, touching it ends the episode unsolved.

    Attributes:
        name: the task's name (``--low-data-tasks``, ``success/<name>`` columns).
        description: one sentence (language conditioning).
        target: the box of states that solve the task, ``((x_lo, y_lo), (x_hi, y_hi))``.
        hazard: a box of states that end the episode as a failure, or None.
    """

    name: str
    description: str
    target: Box
    hazard: Box | None = None


class RewardTaskEnv(NativeEnv):
    """``num_envs`` copies of a 2-D world with region tasks; subclasses give the dynamics.

    Subclasses set the spaces, implement ``_start(n)`` (start positions ``[n, 2]``), ``_move(position,
    action)``, ``_observation(position)`` and ``position_of(observation)`` (its inverse, for scoring
    stored data), and ``expert_action(obs)``.

    Args:
        tasks: the tasks, one `RegionTask` each.
        num_envs: copies stepped in parallel.
        device: where the state lives.
        horizon: steps before truncation.
        task_weights: relative share of episodes of each task when tasks are drawn (default equal).
        task_sampling: ``uniform`` (a task drawn by ``task_weights`` at every reset) or ``fixed``
            (copy ``i`` always has task ``i % T``: evaluation, datasets).
        seed: seed of the environment's generator.
    """

    terminate_on_success = True

    def __init__(
        self,
        tasks: Sequence[RegionTask],
        num_envs: int,
        device: str | torch.device,
        horizon: int,
        task_weights: Sequence[float] | None = None,
        task_sampling: Literal["uniform", "fixed"] = "uniform",
        seed: int | None = None,
    ) -> None:
        if num_envs < 1 or horizon < 1:
            raise ValueError(f"num_envs and horizon must be >= 1 (got {num_envs}, {horizon})")
        if task_sampling not in ("uniform", "fixed"):
            raise ValueError(f"task_sampling must be uniform or fixed; got {task_sampling!r}")
        self.tasks = tuple(tasks)
        self.task_set = TaskSet.from_pairs((t.name, t.description) for t in self.tasks)
        self.num_tasks = len(self.tasks)
        self.num_envs, self.horizon, self.device = num_envs, horizon, torch.device(device)
        weights = [1.0] * self.num_tasks if task_weights is None else [float(w) for w in task_weights]
        if len(weights) != self.num_tasks or min(weights) < 0 or sum(weights) <= 0:
            raise ValueError(f"task_weights: {self.num_tasks} non-negative weights, not all 0 (got {weights})")
        self.task_weights = torch.tensor(weights, device=self.device)

        def boxes(pick) -> torch.Tensor:
            none = ((np.inf, np.inf), (-np.inf, -np.inf))  # an empty box: nothing is inside it
            return torch.tensor([pick(t) or none for t in self.tasks], dtype=torch.float32, device=self.device)

        self.target = boxes(lambda t: t.target)  # [T, 2 (lo, hi), 2 (x, y)]
        self.hazard = boxes(lambda t: t.hazard)
        self.task_sampling = task_sampling
        self.generator = torch.Generator(device=self.device)
        self.generator.manual_seed(seed if seed is not None else int(np.random.SeedSequence().entropy % 2**63))
        self.t = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self.task = torch.arange(num_envs, device=self.device) % self.num_tasks
        self.slot_tasks = self.task.clone() if task_sampling == "fixed" else None
        self.position = self._start(num_envs)

    # ------------------------------------------------------------------ subclass hooks
    def _start(self, n: int) -> torch.Tensor:
        raise NotImplementedError

    def _move(self, position: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _observation(self, position: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def position_of(self, observation: torch.Tensor) -> torch.Tensor:
        """The ``[B, 2]`` positions of stored observations (the inverse of the observation map)."""
        raise NotImplementedError

    def expert_action(self, obs: Obs) -> torch.Tensor:
        """The scripted expert's action for each row of ``obs`` (its own ``task``)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ dynamics
    def _reset_where(self, mask: torch.Tensor) -> None:
        n = int(mask.sum())
        if not n:
            return
        self.position[mask] = self._start(n)
        if self.task_sampling == "uniform":
            self.task[mask] = torch.multinomial(self.task_weights, n, replacement=True, generator=self.generator)
        self.t[mask] = 0

    def _obs(self) -> Obs:
        return {"observation": self._observation(self.position), "task": self.task.clone()}

    def step(self, action: torch.Tensor) -> StepResult:
        self.position = self._move(self.position, torch.as_tensor(action, device=self.device))
        self.t += 1
        success, failed = self._inside(self.target, self.position, self.task), self._inside(self.hazard, self.position, self.task)
        return self._end_step(success.float(), success, failed & ~success)

    # ------------------------------------------------------------------ task functions (any row, any task)
    @staticmethod
    def _inside(boxes: torch.Tensor, position: torch.Tensor, task: torch.Tensor) -> torch.Tensor:
        box = boxes[task.long()]
        return ((position >= box[:, 0]) & (position <= box[:, 1])).all(-1)

    def task_success(self, next_obs: Obs, task: torch.Tensor) -> torch.Tensor:
        """``success_j(s')`` for each row, ``j = task[row]``."""
        return self._inside(self.target, self.position_of(next_obs["observation"]), task.to(self.device))

    def task_failure(self, next_obs: Obs, task: torch.Tensor) -> torch.Tensor:
        """``failure_j(s')``: ``s'`` in task j's hazard (and not in its target)."""
        position = self.position_of(next_obs["observation"])
        task = task.to(self.device)
        return self._inside(self.hazard, position, task) & ~self._inside(self.target, position, task)

    def task_reward(self, obs: Obs, action: torch.Tensor, next_obs: Obs, task: torch.Tensor) -> torch.Tensor:
        """``r_j(s, a, s')`` of each row under ``task[row]``: 1 on success, else 0."""
        return self.task_success(next_obs, task).float()

    def task_terminated(self, next_obs: Obs, task: torch.Tensor) -> torch.Tensor:
        """Whether the transition ends an episode of ``task[row]``: success or failure."""
        return self.task_success(next_obs, task) | self.task_failure(next_obs, task)

    def render_rgb(self, index: int = 0) -> Any:
        """A picture of copy ``index``: every target region (its task's in green) and the position."""
        from taskrl.envs.render import draw_points

        task = int(self.task[index])
        centres = self._unit((self.target[:, 0] + self.target[:, 1]) / 2)
        regions = [(c.cpu().numpy(), 0.08, i == task) for i, c in enumerate(centres)]
        return draw_points(self._unit(self.position[index : index + 1])[0].cpu().numpy(), regions)

    def _unit(self, position: torch.Tensor) -> torch.Tensor:
        """Positions in the picture's box ``[-1, 1]^2``."""
        return position


def reward_task_family(
    name: str, description: str, env_class: type[RewardTaskEnv], tasks: Sequence[RegionTask], gym_id: str, actions: str
) -> EnvFamily:
    """The env family of ``env_class`` with ``tasks``: training copies with the section's task weights,
    evaluation copies with fixed tasks (copy i on task i % T, ``eval_episodes`` of each)."""
    names = [t.name for t in tasks]

    def make(settings: RewardTaskSettings, request: EnvRequest) -> RewardTaskEnv:
        if request.evaluation:
            return env_class(len(tasks) * request.eval_episodes, request.device, task_sampling="fixed", seed=request.seed)
        weights = task_weights(names, settings.low_data_tasks, settings.low_data_fraction)
        return env_class(request.num_envs, request.device, task_weights=weights, seed=request.seed)

    def demos(chosen: Sequence[str] | None) -> DemoSource:
        """The scripted expert the offline datasets use (``expert_action``), for ``taskrl demos collect``; an
        episode counts when it ends in the task's region (episodes end at success)."""
        if chosen is not None and sorted(chosen) != sorted(names):
            raise ValueError(f"{name} records all its tasks ({', '.join(names)}): give {name} alone")

        def make_env(wanted: Sequence[str], copies: int, seed: int, after_success: int) -> RewardTaskEnv:
            return env_class(len(tasks) * copies, "cpu", task_sampling="fixed", seed=seed)

        task_set = TaskSet.from_pairs((t.name, t.description) for t in tasks)
        return DemoSource(name, task_set, make_env, lambda env: env.expert_action, "any")

    return EnvFamily(
        name=name,
        description=description,
        section=name,
        settings=RewardTaskSettings,
        make=make,
        check=lambda settings, run: settings.check_tasks(names),
        kind="multitask",
        actions=actions,
        per_task_success="any",  # episodes end at success
        video_env=lambda settings: gym.make(gym_id, render_mode="rgb_array"),
        task_rewards=True,
        demos=demos if actions == "box" else None,  # demonstration datasets hold actions in [-1, 1]
    )


def split_names(text: str) -> list[str]:
    """``"a, b"`` -> ``["a", "b"]``."""
    return [name.strip() for name in text.split(",") if name.strip()]


def task_weights(names: Sequence[str], low_data_tasks: str, low_data_fraction: float) -> list[float]:
    """1 for every task, ``low_data_fraction`` for the low-data ones (names, comma-separated)."""
    low = set(split_names(low_data_tasks))
    return [low_data_fraction if name in low else 1.0 for name in names]


def parse_qualities(text: str, names: Sequence[str]) -> dict[str, str]:
    """``"A=expert,B=random"`` -> the quality of every task's dataset (unnamed tasks: ``random``)."""
    qualities = dict.fromkeys(names, "random")
    for item in filter(None, (part.strip() for part in text.split(","))):
        task, sep, quality = item.partition("=")
        require(sep == "=", "dataset_quality", f"expected TASK=QUALITY, got {item!r}")
        require(task.strip() in qualities, "dataset_quality", f"unknown task {task.strip()!r}; allowed: {', '.join(names)}")
        require(
            quality.strip() in QUALITIES,
            "dataset_quality",
            f"unknown quality {quality.strip()!r}; allowed: {', '.join(QUALITIES)}",
        )
        qualities[task.strip()] = quality.strip()
    return qualities


@dataclasses.dataclass
class RewardTaskSettings:
    """Settings of the reward-task families (``gridtasks``, ``pointtasks``).

    Attributes:
        low_data_tasks: tasks that get fewer training episodes (names, comma-separated): MT-Opt's imbalance.
        low_data_fraction: their share of episodes relative to every other task, in [0, 1].
        dataset_quality: offline datasets of the run (``TASK=QUALITY,...``; quality ``expert`` (the
            scripted expert), ``medium`` (the expert with half its actions uniformly random) or
            ``random``; tasks not named: ``random``); empty: no dataset. Stored in the replay before
            training, as CDS's per-task datasets of different quality.
        dataset_steps: transitions of each task's dataset.
    """

    low_data_tasks: str = ""
    low_data_fraction: float = 0.1
    dataset_quality: str = ""
    dataset_steps: int = 2_000

    def validate(self) -> None:
        require(0.0 <= self.low_data_fraction <= 1.0, "low_data_fraction", f"must be in [0, 1] (got {self.low_data_fraction})")
        require(self.dataset_steps >= 1, "dataset_steps", f"must be >= 1 (got {self.dataset_steps})")

    def check_tasks(self, names: Sequence[str]) -> None:
        """The named tasks exist in the family, and some task is collected."""
        low = split_names(self.low_data_tasks)
        unknown = [t for t in low if t not in names]
        if unknown:
            raise ConfigError("low_data_tasks", f"unknown task {unknown[0]!r}; allowed: {', '.join(names)}")
        if set(names) <= set(low) and self.low_data_fraction == 0:
            raise ConfigError("low_data_fraction", "0 for every task leaves no task to collect")
        parse_qualities(self.dataset_quality, names)
