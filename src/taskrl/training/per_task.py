"""Per-task evaluation: Meta-World's protocol, for any batched env whose observations carry ``task``.

Per task, a fixed number of episodes (over distinct goal positions where the env can pin them);
an episode succeeds if it reaches success at any step (Meta-World) or at its final step (where
touring several goals would otherwise count); the headline is the mean over tasks.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from taskrl.envs.base import BatchedEnv
from taskrl.tasks import TaskSet
from taskrl.training.evaluation import UNLIMITED_EPISODE_STEPS, episodes_ended, seed_acting
from taskrl.types import Obs

__all__ = ["TooManyEpisodes", "evaluate_per_task"]

#: Meta-World draws 50 goal positions per task; its protocol evaluates one episode on each.
DEFAULT_EPISODES_PER_TASK = 50


class TooManyEpisodes(ValueError):
    """More episodes per task than the env has distinct goal positions to run them on."""


@torch.no_grad()
def evaluate_per_task(
    policy: Callable[[Obs], torch.Tensor],
    env: BatchedEnv | Callable[[], BatchedEnv],
    episodes_per_task: int = DEFAULT_EPISODES_PER_TASK,
    seed: int = 0,
    task_set: TaskSet | None = None,
    save_to: str | Path | None = None,
    max_steps: int | None = None,
    success: Literal["any", "final"] = "any",
) -> dict[str, Any]:
    """Per-task success following Meta-World's protocol; the headline is the mean over tasks.

    For each task, ``episodes_per_task`` episodes are run (over distinct goal positions where
    the env can pin them, as [`MetaWorldMultiTaskEnv`][taskrl.envs.meta_world.MetaWorldMultiTaskEnv] does: episode ``j`` of a task uses
    goal ``j``, so ``episodes_per_task <= 50`` visits 50 distinct goals); an episode succeeds if
    ``info["is_success"]`` is true at ANY of its steps. Works on any batched env whose
    observations carry ``task``: with fixed tasks per slot (``slot_tasks``), each slot runs its
    share of its task's episodes; otherwise episodes are counted by the task they started with
    until every task has enough.

    Args:
        policy: ``obs -> action`` (greedy / deterministic actions are the caller's choice).
        env: a batched env, or a zero-argument factory of one (closed afterwards).
        episodes_per_task: episodes per task (Meta-World: 50, one per goal position).
        seed: ``env.reset(seed)`` seed, so repeated evaluations are comparable.
        task_set: names and descriptions of the tasks (default ``env.task_set``).
        save_to: write the result as JSON to this path.
        max_steps: safety cap on env steps (default: generous, from the horizon).
        success: ``"any"`` (Meta-World: reached at any step of the episode) or ``"final"``
            (``is_success`` at the step the episode ends, as [`taskrl.training.evaluation.evaluate`][taskrl.training.evaluation.evaluate]).

    Returns:
        A JSON-able dict: ``mean_success_rate`` (the headline), ``episodes_per_task``,
        ``distinct_goals`` (whether goal positions were pinned), and ``tasks``: one entry per
        task with ``index``, ``description``, ``success_rate``, ``episodes``, ``mean_return``,
        ``mean_length``.
    """
    if not isinstance(episodes_per_task, int) or episodes_per_task < 1:
        raise ValueError(f"episodes_per_task must be an integer >= 1, got {episodes_per_task!r}")
    if success not in ("any", "final"):
        raise ValueError(f"success must be 'any' or 'final', got {success!r}")
    owned = not isinstance(env, BatchedEnv)
    if owned:
        if not callable(env):
            raise ValueError(f"env must be a batched env or a zero-argument factory of one, got {env!r}")
        env = env()
    try:
        return _evaluate_per_task(policy, env, episodes_per_task, seed, task_set, save_to, max_steps, success)
    finally:
        if owned:
            env.close()


def _slot_quotas(slot_tasks: torch.Tensor, n: int) -> tuple[torch.Tensor, list[list[int]]]:
    """Episodes each slot runs so that every task gets ``n``, and the goal indices of each slot."""
    quotas = torch.zeros(slot_tasks.shape[0], dtype=torch.long)
    goals: list[list[int]] = [[] for _ in range(slot_tasks.shape[0])]
    for task in slot_tasks.unique().tolist():
        slots = torch.nonzero(slot_tasks == task).flatten().tolist()
        for j in range(n):  # goal j of the task goes to its (j mod copies)-th slot
            goals[slots[j % len(slots)]].append(j)
        for s in slots:
            quotas[s] = len(goals[s])
    return quotas, goals


def _evaluate_per_task(policy, env, n, seed, task_set, save_to, max_steps, criterion) -> dict[str, Any]:
    task_set = task_set if task_set is not None else getattr(env, "task_set", None)
    if task_set is None:
        raise ValueError("evaluate_per_task needs the env's task_set (env.task_set) or task_set=...")
    if "task" not in env.single_observation_space.spaces:
        raise ValueError(
            f"evaluate_per_task needs observations with a 'task' key; found {list(env.single_observation_space.spaces)}"
        )
    num_tasks, num_envs = len(task_set), env.num_envs
    slot_tasks = getattr(env, "slot_tasks", None)
    pinned = False
    quotas = None
    if slot_tasks is not None:
        slot_tasks = slot_tasks.detach().cpu().long()
        missing = sorted(set(range(num_tasks)) - set(slot_tasks.tolist()))
        if missing:
            raise ValueError(f"no env slot runs tasks {[task_set[i].name for i in missing]}")
        quotas, goals = _slot_quotas(slot_tasks, n)
        if callable(getattr(env, "set_goal_schedules", None)):
            available = env.goal_positions() if callable(getattr(env, "goal_positions", None)) else n
            if n > available:
                raise TooManyEpisodes(f"episodes_per_task={n} exceeds the {available} distinct goal positions per task")
            env.set_goal_schedules([g or None for g in goals])
            pinned = True
    if max_steps is None:
        rounds = math.ceil(n * num_tasks / num_envs) if quotas is None else int(quotas.max())
        max_steps = (env.horizon or UNLIMITED_EPISODE_STEPS) * (rounds + 1) * (1 if quotas is not None else 20)

    successes = torch.zeros(num_tasks, dtype=torch.long)
    episodes = torch.zeros(num_tasks, dtype=torch.long)
    returns = torch.zeros(num_tasks, dtype=torch.float64)
    lengths = torch.zeros(num_tasks, dtype=torch.float64)
    done_slot = torch.zeros(num_envs, dtype=torch.long)  # episodes recorded per slot
    try:
        obs = env.reset(seed=seed)
        seed_acting(policy, seed)
        episodes_ended(policy, torch.ones(num_envs, dtype=torch.bool))
        ep_task = obs["task"].detach().cpu().long().clone()
        ep_success = torch.zeros(num_envs, dtype=torch.bool)
        ep_return = torch.zeros(num_envs, dtype=torch.float64)
        ep_length = torch.zeros(num_envs, dtype=torch.long)
        steps = 0
        while True:
            if quotas is not None and bool((done_slot >= quotas).all()):
                break
            if quotas is None and bool((episodes >= n).all()):
                break
            if steps >= max_steps:
                short = [task_set[i].name for i in range(num_tasks) if episodes[i] < n]
                raise RuntimeError(f"evaluation stopped after {steps} steps with too few episodes for tasks {short}")
            obs, reward, terminated, truncated, info = env.step(policy(obs))
            steps += 1
            now = info["is_success"].detach().cpu().bool().clone()
            ep_success = ep_success | now if criterion == "any" else now
            ep_return += reward.detach().cpu().double()
            ep_length += 1
            ended = (terminated | truncated).detach().cpu()
            episodes_ended(policy, ended)
            for s in torch.nonzero(ended).flatten().tolist():
                t = int(ep_task[s])
                keep = done_slot[s] < quotas[s] if quotas is not None else episodes[t] < n
                if keep:
                    episodes[t] += 1
                    successes[t] += int(ep_success[s])
                    returns[t] += ep_return[s]
                    lengths[t] += ep_length[s]
                    done_slot[s] += 1
            if bool(ended.any()):
                ep_task[ended] = obs["task"].detach().cpu().long()[ended]
                ep_success[ended], ep_return[ended], ep_length[ended] = False, 0.0, 0
    finally:
        if pinned:
            env.set_goal_schedules(None)

    tasks = {}
    for spec in task_set:
        k = max(int(episodes[spec.index]), 1)
        tasks[spec.name] = {
            "index": spec.index,
            "description": spec.description,
            "success_rate": float(successes[spec.index]) / k,
            "episodes": int(episodes[spec.index]),
            "mean_return": float(returns[spec.index]) / k,
            "mean_length": float(lengths[spec.index]) / k,
        }
    result = {
        "mean_success_rate": float(np.mean([v["success_rate"] for v in tasks.values()])),
        "episodes_per_task": n,
        "distinct_goals": pinned,
        "success": "reached at any step" if criterion == "any" else "at the final step",
        "tasks": tasks,
    }
    if save_to is not None:
        path = Path(save_to)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(json.dumps(result, indent=2) + "\n")
        tmp.replace(path)
    return result
