"""The ``tasks`` family: a multi-task run over a user's own list of tasks.

A [`TaskSet`][taskrl.tasks.TaskSet] (in Python) or a task file (``--task-file tasks.yaml``) names each
task, describes it in one sentence (what language conditioning embeds) and says where it runs:

- every task a gymnasium env (an id with ``env_kwargs``, or a factory): `TaskSetEnv` runs
  ``envs_per_task`` copies of each, and adds the task index to the observation under ``task``;
- no task with an env: the names are Meta-World tasks, run as
  [`MetaWorldMultiTaskEnv`][taskrl.envs.meta_world.MetaWorldMultiTaskEnv] with the user's descriptions.

The task envs must share observation and action spaces (one network serves all of them).
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.gymnasium_adapter import VECTOR_STRATEGIES, GymnasiumVectorEnv, VectorStrategy, _make_env
from taskrl.envs.gymnasium_family import PYTHON_SOURCE, check_registered, factory_name
from taskrl.envs.spec import EnvFamily, EnvRequest
from taskrl.errors import ConfigError, one_of, require
from taskrl.tasks import TaskSet, TaskSpec

__all__ = ["FAMILY", "TaskIndexWrapper", "TaskSetEnv", "TaskSetSettings"]


class TaskIndexWrapper(gym.ObservationWrapper):
    """One task's env with its index added to the observation: ``{..., "task": index}``.

    A ``Box`` observation becomes ``{"observation": obs, "task": index}``; a ``Dict`` gains the key.
    """

    def __init__(self, env: gym.Env, index: int, num_tasks: int) -> None:
        super().__init__(env)
        self.index = index
        space = env.observation_space
        entries = dict(space.spaces) if isinstance(space, gym.spaces.Dict) else {"observation": space}
        if "task" in entries:
            raise ValueError("a task's env must not have a 'task' observation key already (taskrl adds it)")
        self.observation_space = gym.spaces.Dict({**entries, "task": gym.spaces.Discrete(num_tasks)})
        self._dict = isinstance(space, gym.spaces.Dict)

    def observation(self, observation: Any) -> dict[str, Any]:
        entries = dict(observation) if self._dict else {"observation": observation}
        return {**entries, "task": np.int64(self.index)}


def _task_env(task: TaskSpec, num_tasks: int, max_episode_steps: int | None) -> gym.Env:
    """Module-level (picklable) factory of one copy of ``task``'s env, for async workers too."""
    if isinstance(task.env, str):
        env = _make_env(task.env, dict(task.env_kwargs or {}), max_episode_steps)
    else:
        env = task.env()
        if max_episode_steps is not None:
            env = gym.wrappers.TimeLimit(env, max_episode_steps=max_episode_steps)
    return TaskIndexWrapper(env, task.index, num_tasks)


class TaskSetEnv(GymnasiumVectorEnv):
    """``envs_per_task`` copies of every task's gymnasium env, the task index in each observation.

    Slots are task-major: slot ``s`` runs task ``s // envs_per_task`` (``slot_tasks``), which the
    per-task evaluator uses.

    Args:
        task_set: the tasks; every one must have an ``env`` (id or factory).
        envs_per_task: copies of each task.
        device: torch device of every returned tensor.
        max_episode_steps: time limit of every copy (``None``: each env's registered one).
        success_key: step-info key of success (``auto``: ``is_success`` or ``success``).
        vector_strategy: ``sync`` or ``async``.
    """

    def __init__(
        self,
        task_set: TaskSet,
        envs_per_task: int = 1,
        device: str | torch.device = "cpu",
        max_episode_steps: int | None = None,
        success_key: str | None = "auto",
        vector_strategy: VectorStrategy = "sync",
    ) -> None:
        missing = [t.name for t in task_set if t.env is None]
        if missing:
            raise ValueError(f"tasks {missing} have no env (a gymnasium id or a factory)")
        if envs_per_task < 1:
            raise ValueError(f"envs_per_task must be >= 1, got {envs_per_task}")
        self.task_set = task_set
        factories = [
            functools.partial(_task_env, t, len(task_set), max_episode_steps) for t in task_set for _ in range(envs_per_task)
        ]
        super().__init__(
            factories,
            device=device,
            vector_strategy=vector_strategy,
            success_key=success_key,
            max_episode_steps=max_episode_steps,
        )
        self.env_id = f"tasks/{'+'.join(task_set.names)}"
        self.slot_tasks = torch.arange(self.num_envs, device=self.device) // envs_per_task


@dataclasses.dataclass
class TaskSetSettings:
    """Settings of the ``tasks`` family (a user's own task set).

    Attributes:
        task_file: a JSON or YAML file listing the tasks (name, description, and env: a gymnasium id
            with env_kwargs; no env: a Meta-World task); given alone it selects this family.
        envs_per_task: training copies of every task (``num_envs`` must be a multiple of the tasks).
        max_episode_steps: episode length; 0 = each env's registered limit (Meta-World: 500).
        success_key: step-info key of success; ``auto`` reads ``is_success`` or ``success``.
        success_at: per-task evaluation counts an episode as a success at ``any`` step or at the
            ``final`` step; ``auto``: any for Meta-World tasks, final otherwise.
        vector_strategy: ``sync`` (one process) or ``async`` (one process per copy).
    """

    task_file: str = ""
    max_episode_steps: int = 0
    success_key: str = "auto"
    success_at: Literal["auto", "any", "final"] = "auto"
    vector_strategy: Literal["sync", "async"] = "sync"

    def validate(self) -> None:
        require(
            bool(self.task_file), "task_file", "name a JSON or YAML file of tasks (or pass a TaskSet to taskrl.train(env=...))"
        )
        require(
            self.max_episode_steps >= 0,
            "max_episode_steps",
            f"must be >= 0 (0 = the registered limit; got {self.max_episode_steps})",
        )
        one_of(self.success_at, ("auto", "any", "final"), "success_at", "criterion")
        one_of(self.vector_strategy, VECTOR_STRATEGIES, "vector_strategy", "strategy")


def _task_set(settings: TaskSetSettings, source: Any) -> TaskSet:
    if source is not None:
        return source
    task_set = _read(settings)
    recorded = [t.name for t in task_set if isinstance(t.env, str) and t.env.startswith(PYTHON_SOURCE)]
    if recorded:
        raise ConfigError(
            "env",
            f"tasks {recorded} were trained on Python factories; pass the TaskSet again "
            f"(taskrl.train(resume=..., env=task_set) or taskrl.load(..., env=task_set))",
        )
    return task_set


def _is_metaworld(task_set: TaskSet) -> bool:
    return all(t.env is None for t in task_set)


def _make(settings: TaskSetSettings, request: EnvRequest) -> GymnasiumVectorEnv:
    task_set = _task_set(settings, request.source)
    steps = settings.max_episode_steps or None
    per_task = 1 if request.evaluation else max(1, request.num_envs // len(task_set))
    if _is_metaworld(task_set):
        from taskrl.envs.meta_world import METAWORLD_HORIZON, MetaWorldMultiTaskEnv

        try:
            env = MetaWorldMultiTaskEnv(
                task_set.names,
                use_one_hot=True,
                envs_per_task=per_task,
                max_episode_steps=steps or METAWORLD_HORIZON,
                seed=request.run_seed,
                device=request.device,
                vector_strategy=settings.vector_strategy,
            )
        except ValueError as error:
            raise ConfigError("task_file", f"{error} (a task without an env is a Meta-World task)") from None
        env.task_set = task_set  # the user's descriptions
        return env
    if any(t.env is None for t in task_set):
        raise ConfigError("task_file", "give every task an env (a gymnasium id or a factory), or none (Meta-World tasks)")
    for t in task_set:
        if isinstance(t.env, str):
            check_registered(t.env)
    try:
        return TaskSetEnv(task_set, per_task, request.device, steps, settings.success_key, settings.vector_strategy)
    except (ValueError, AssertionError) as error:  # spaces that differ between tasks, bad observation spaces
        raise ConfigError("task_file", f"the tasks' envs do not fit one multi-task env: {error}") from None


def _read(settings: TaskSetSettings) -> TaskSet:
    try:
        return TaskSet.from_file(settings.task_file)
    except (OSError, ValueError) as error:
        raise ConfigError("task_file", str(error)) from None


def _check(settings: TaskSetSettings, run: Any) -> None:
    tasks = len(_read(settings))
    require(
        run.num_envs % tasks == 0,
        "num_envs",
        f"must be a multiple of the {tasks} tasks (one or more copies per task; got {run.num_envs})",
    )


def _success_at(settings: TaskSetSettings) -> str:
    if settings.success_at != "auto":
        return settings.success_at
    return "any" if _is_metaworld(_read(settings)) else "final"


def _persist(task_set: TaskSet, run_dir: Path) -> dict[str, Any]:
    """Write the task set to ``run_dir/tasks.json`` (factories recorded by name) and point at it."""
    import json

    path = Path(run_dir) / "tasks.json"
    path.write_text(json.dumps({"tasks": task_set.to_entries(factory_name)}, indent=2) + "\n")
    return {"task_file": str(path)}


FAMILY = EnvFamily(
    name="tasks",
    description="your own task set (--task-file FILE, or a TaskSet in Python): gymnasium envs or Meta-World tasks",
    section="tasks",
    settings=TaskSetSettings,
    make=_make,
    kind="multitask",
    per_task_success=_success_at,
    check=_check,
    selected_by="task_file",
    accepts=lambda obj: isinstance(obj, TaskSet),
    persist=_persist,
)
