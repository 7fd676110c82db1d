"""What the registry knows about an environment family: `EnvFamily`, and what a run asks
of it: `EnvRequest`. Each family's file declares its families next to its environments."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import torch

from taskrl.envs.base import BatchedEnv, is_goal_env

__all__ = ["DemoSource", "EnvFamily", "EnvKind", "EnvRequest", "Expert", "env_kind"]

#: ``goal``: observations carry achieved / desired goals and the env has ``compute_reward`` (hindsight
#: relabelling applies); ``multitask``: observations carry a task index under ``task``; ``plain``: neither.
EnvKind = Literal["goal", "multitask", "plain"]


def env_kind(env: Any) -> EnvKind:
    """The kind of a built env (or of anything with its spaces)."""
    if is_goal_env(env):
        return "goal"
    space = env.single_observation_space
    return "multitask" if isinstance(space, gym.spaces.Dict) and "task" in space.spaces else "plain"


@dataclasses.dataclass(frozen=True)
class EnvRequest:
    """What a run asks of an env family.

    Attributes:
        num_envs: training copies (evaluation envs choose their own from ``eval_episodes``).
        seed: seed of the env's random generator.
        device: where its tensors live.
        evaluation: build the evaluation env (fixed tasks per copy, goal schedules).
        eval_episodes: evaluation episodes (per task on multi-task envs).
        run_seed: the run's seed (Meta-World draws its goal positions from it).
        source: a Python object the env is built from instead of a name (a factory of a
            ``gymnasium.Env``, a [`TaskSet`][taskrl.tasks.TaskSet]), for families that accept one.
    """

    num_envs: int
    seed: int
    device: torch.device
    evaluation: bool = False
    eval_episodes: int = 1
    run_seed: int = 0
    source: Any = None

    @property
    def copies(self) -> int:
        """Copies of a single-task env: ``num_envs`` for training, one per episode for evaluation."""
        return self.eval_episodes if self.evaluation else self.num_envs


#: ``obs -> actions``: a batched scripted expert.
Expert = Callable[[dict[str, torch.Tensor]], torch.Tensor]


@dataclasses.dataclass(frozen=True)
class DemoSource:
    """A task set whose tasks have a scripted expert: what ``taskrl demos collect`` records.

    Attributes:
        name: what ``taskrl demos collect`` was given.
        task_set: the tasks, in index order.
        make_env: ``(task names, copies per task, seed, after_success) -> batched env`` whose slot ``s`` runs
            task ``names[s // copies]`` (``slot_tasks``), episodes ending at the horizon or, where
            ``success`` is ``any``, ``after_success`` steps after the first success.
        expert: ``env -> (obs -> actions)``: the batched expert of that env's slots.
        success: ``any`` (the episode ends at its first success) or ``final`` (success at the last step).
        splits: named task lists (ML45's ``train`` and ``test``), recorded in the dataset card.
        cameras: ``make_env`` also takes ``image_size=N`` and then gives each state's rendered picture as ``image``
            beside the state the expert reads (what ``taskrl demos collect --pictures N`` records).
    """

    name: str
    task_set: Any
    make_env: Callable[[Sequence[str], int, int, int], BatchedEnv]
    expert: Callable[[BatchedEnv], Expert]
    success: Literal["any", "final"]
    splits: dict[str, list[str]] = dataclasses.field(default_factory=dict)
    cameras: bool = False


@dataclasses.dataclass(frozen=True)
class EnvFamily:
    """One environment family, as runs and the command line see it.

    Attributes:
        name: the value of ``--env``.
        description: one line for ``--help``.
        section: the name of its settings section in ``config.json`` (families may share one).
        settings: its settings dataclass; a ``validate()`` method raises ``ConfigError``.
        make: ``make(settings, request) -> BatchedEnv``.
        kind: ``goal``, ``multitask`` or ``plain``; ``None`` when only the built env can tell (any
            gymnasium id), and then it is checked once the env is built.
        actions: ``discrete`` or ``box`` when known before building.
        per_task_success: multi-task evaluation's success criterion, ``any`` step (Meta-World's
            protocol) or the ``final`` step; or a function of the settings giving one.
        spec: ``spec(settings, request) -> object with single_observation_space, single_action_space
            (and task_set)``: what loading an agent needs, without building a slow env.
        check: ``check(settings, run_config)``: rules between the section and run-level settings
            (e.g. ``num_envs`` a multiple of the tasks).
        selected_by: a setting of the section that selects this family when given alone
            (``--env-id X`` trains on the gymnasium id X).
        accepts: ``accepts(obj) -> bool``: the Python objects this family builds envs from.
        persist: ``persist(obj, run_dir) -> settings``: how a run records such an object in its
            settings (and files of its own in the run directory), so the run can be resumed and loaded.
        tasks_env: multi-task families: ``tasks_env(settings, request, names) -> env`` of other tasks of the
            family (held-out tasks a prompted policy is evaluated on), one copy per named task, task i = names[i].
        task_sentences: multi-task families: ``task_sentences(settings) -> {name: [description, paraphrase, ...]}``
            of every task ``tasks_env`` can build: what a sentence given to ``taskrl eval --task`` is
            matched against, and the paraphrases held-out prompts are tested with.
        video_env: ``video_env(settings) -> gymnasium.Env`` with ``render_mode="rgb_array"``: one copy to
            record videos of (``taskrl eval --video``); None where the family cannot render.
        task_rewards: whether its tasks are reward functions (``task_reward``, ``task_terminated``, ``task_success`` on
            the env: what data sharing scores rows with); None where only the built env can tell (a user's env).
        images: whether its observations carry a camera picture (``image``), which only algorithms that
            declare ``images`` can read.
        scripted: whether its env has a scripted exploration policy (``scripted_action(obs)``, what
            ``--scripted-exploration`` hands episodes to); None where only the built env can tell (a user's env).
        demos: families with a scripted expert: ``demos(task names or None) -> DemoSource`` of the named tasks (None:
            the family's own set), what ``taskrl demos collect FAMILY`` (or ``FAMILY:task,task``) records.
        held_out: families with objects never seen in training: ``held_out(settings) -> settings`` of the same env
            on those objects, what ``taskrl eval RUN --held-out`` evaluates a run of any algorithm on.
    """

    name: str
    description: str
    section: str
    settings: type
    make: Callable[[Any, EnvRequest], BatchedEnv]
    kind: EnvKind | None = None
    actions: Literal["discrete", "box"] | None = None
    per_task_success: str | Callable[[Any], str] = "final"
    spec: Callable[[Any, EnvRequest], Any] | None = None
    check: Callable[[Any, Any], None] | None = None
    selected_by: str | None = None
    accepts: Callable[[Any], bool] | None = None
    persist: Callable[[Any, Path], dict[str, Any]] | None = None
    video_env: Callable[[Any], Any] | None = None
    tasks_env: Callable[[Any, EnvRequest, Sequence[str]], BatchedEnv] | None = None
    task_sentences: Callable[[Any], dict[str, list[str]]] | None = None
    task_rewards: bool | None = False
    demos: Callable[[Sequence[str] | None], DemoSource] | None = None
    images: bool = False
    scripted: bool | None = False
    held_out: Callable[[Any], Any] | None = None

    def success_criterion(self, settings: Any) -> str:
        """``any`` or ``final``: when a multi-task evaluation episode counts as a success."""
        rule = self.per_task_success
        return rule(settings) if callable(rule) else rule
