"""Where demonstrations come from: a task set, its envs and a scripted expert for every task.

``taskrl demos collect SOURCE`` names a :class:`DemoSource`:

- ``mt10``, ``mt50``: Meta-World's task sets, each task's scripted v3 expert from
  ``metaworld.policies`` (``ENV_POLICY_MAP``), goal positions resampled every episode;
- ``ml45``: all 50 tasks, with Meta-World's ML45 split (45 training, 5 test tasks) in the card, so one
  dataset serves training and one-demonstration prompts of the held-out tasks;
- a comma-separated list of Meta-World task names (``reach,push``);
- ``pointreach-mt``: the native multi-task point reaching tasks, with the optimal controller
  (straight to the region at full speed, then stay).

A source says when a demonstration counts: Meta-World episodes end ``after_success`` steps after
their first success (success at any step is Meta-World's protocol; the steps after it show the
expert settling at the goal, which precise tasks such as reach need), PointReach episodes run their
50 steps and count when they end inside the region (its per-task criterion).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable, Sequence
from typing import Any, Literal

import numpy as np
import torch

from taskrl.envs.base import BatchedEnv
from taskrl.errors import ConfigError
from taskrl.tasks import TaskSet

__all__ = ["DemoSource", "demo_source"]


Expert = Callable[[dict[str, torch.Tensor]], torch.Tensor]


@dataclasses.dataclass(frozen=True)
class DemoSource:
    """A task set whose tasks have a scripted expert.

    Attributes:
        name: what ``taskrl demos collect`` was given.
        task_set: the tasks, in index order.
        make_env: ``(task names, copies per task, seed, after_success) -> batched env`` whose slot ``s`` runs
            task ``names[s // copies]`` (``slot_tasks``), episodes ending at the horizon or, where
            ``success`` is ``any``, ``after_success`` steps after the first success.
        expert: ``env -> (obs -> actions)``: the batched expert of that env's slots.
        success: ``any`` (the episode ends at its first success) or ``final`` (success at the last step).
        splits: named task lists (ML45's ``train`` and ``test``), recorded in the dataset card.
    """

    name: str
    task_set: TaskSet
    make_env: Callable[[Sequence[str], int, int, int], BatchedEnv]
    expert: Callable[[BatchedEnv], Expert]
    success: Literal["any", "final"]
    splits: dict[str, list[str]] = dataclasses.field(default_factory=dict)


# ---------------------------------------------------------------------- Meta-World
def _metaworld_source(name: str, benchmark: Any) -> DemoSource:
    from taskrl.envs.metaworld_tasks import ML45_TEST_TASKS, MetaWorldMultiTaskEnv, metaworld_task_set

    def make_env(names: Sequence[str], copies: int, seed: int, after_success: int) -> BatchedEnv:
        return MetaWorldMultiTaskEnv(
            list(names), envs_per_task=copies, seed=seed, terminate_on_success=True, success_hold=after_success
        )

    task_set = metaworld_task_set(benchmark)
    splits = {}
    if name == "ml45":
        splits = {"train": [n for n in task_set.names if n not in ML45_TEST_TASKS], "test": list(ML45_TEST_TASKS)}
    return DemoSource(name, task_set, make_env, _metaworld_expert, "any", splits)


def _metaworld_expert(env: Any) -> Expert:
    try:
        from metaworld.policies import ENV_POLICY_MAP
    except ImportError as error:
        raise ConfigError(
            "source", f"Meta-World experts need the `metaworld` extra: pip install 'taskrl[metaworld]' ({error})"
        ) from None
    from taskrl.envs.metaworld_tasks import metaworld_id

    names = env.task_set.names
    policies = [ENV_POLICY_MAP[metaworld_id(names[int(t)])]() for t in env.slot_tasks.tolist()]

    def act(obs: dict[str, torch.Tensor]) -> torch.Tensor:
        states = obs["observation"].detach().cpu().numpy().astype(np.float64)
        with warnings.catch_warnings():  # the experts warn when their gains exceed the clipped range: noise
            warnings.filterwarnings("ignore", message="Constant\\(s\\) may be too high")
            actions = np.stack([p.get_action(s) for p, s in zip(policies, states)])
        return torch.as_tensor(np.clip(actions, -1.0, 1.0), dtype=torch.float32, device=env.device)

    return act


# ---------------------------------------------------------------------- native PointReach
def _pointreach_source() -> DemoSource:
    from taskrl.envs.multitask_point import DEFAULT_REGIONS, MultiTaskPointReach

    def make_env(names: Sequence[str], copies: int, seed: int, after_success: int) -> BatchedEnv:
        regions = [r for r in DEFAULT_REGIONS if r[0] in names]  # episodes run their 50 steps: no cut at success
        return MultiTaskPointReach(num_envs=len(regions) * copies, regions=regions, task_sampling="fixed", seed=seed)

    def expert(env: Any) -> Expert:
        def act(obs: dict[str, torch.Tensor]) -> torch.Tensor:
            offset = env.centres[obs["task"].long()] - obs["observation"]
            return (offset / env.max_speed).clamp(-1.0, 1.0)

        return act

    task_set = TaskSet.from_pairs((name, description) for name, description, _ in DEFAULT_REGIONS)
    return DemoSource("pointreach-mt", task_set, make_env, expert, "final")


# ---------------------------------------------------------------------- by name
SOURCES = ("mt10", "mt50", "ml45", "pointreach-mt")


def demo_source(name: str) -> DemoSource:
    """The source ``taskrl demos collect`` names: ``mt10``, ``mt50``, ``ml45``, ``pointreach-mt`` or
    a comma-separated list of Meta-World tasks; a :class:`ConfigError` on ``source`` otherwise."""
    if not isinstance(name, str) or not name.strip():
        raise ConfigError("source", f"expected one of {', '.join(SOURCES)} or Meta-World task names separated by commas")
    key = name.strip().lower()
    if key == "pointreach-mt":
        return _pointreach_source()
    try:
        if key in ("mt10", "mt50"):
            return _metaworld_source(key, key.upper())
        if key == "ml45":
            return _metaworld_source(key, "MT50")
        return _metaworld_source(key, [n.strip() for n in key.split(",") if n.strip()])
    except ValueError as error:
        raise ConfigError("source", f"{error}; or a source: {', '.join(SOURCES)}") from None
