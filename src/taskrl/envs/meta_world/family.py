"""The Meta-World families (``mt1``, ``mt10``, ``mt50``, ``ml45``; section ``metaworld``), their
demonstration sources and the scripted experts (Meta-World's ``metaworld.policies``)."""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np
import torch

from taskrl.envs.base import BatchedEnv
from taskrl.envs.camera import CameraSettings
from taskrl.envs.gymnasium_adapter import VECTOR_STRATEGIES
from taskrl.envs.meta_world.catalogue import (
    METAWORLD_DESCRIPTIONS,
    METAWORLD_GOAL,
    METAWORLD_HORIZON,
    METAWORLD_NUM_GOALS,
    METAWORLD_PARAPHRASES,
    ML45_TEST_TASKS,
    ML45_TRAIN_TASKS,
    MT50_TASKS,
    hide_goal,
    metaworld_id,
    metaworld_spec,
    metaworld_task_set,
    version_free,
)
from taskrl.envs.meta_world.env import MetaWorldMultiTaskEnv, MetaWorldVideoEnv
from taskrl.envs.pixels import check_pixel_settings
from taskrl.envs.spec import DemoSource, EnvFamily, EnvRequest, Expert
from taskrl.errors import ConfigError, one_of, require


@dataclasses.dataclass
class MetaWorldSettings(CameraSettings):
    """Settings of the Meta-World families (``mt1``, ``mt10``, ``mt50``).

    Attributes:
        task: the task of ``mt1`` (``reach``, ``push``, ... or with its ``-v3`` suffix).
        max_episode_steps: episode length (Meta-World's own is 500).
        vector_strategy: ``sync`` or ``async`` (one process per copy).
        eval_until_success: end evaluation episodes at their first success. Meta-World counts success at
            any step, so every episode's outcome is the same and evaluation is faster; the evaluation
            return and length then stop at the success (training episodes are unchanged).
        hidden_goal: ML45's protocol: the goal position in the observation is zeroed (Meta-World's ML
            benchmarks), in the env and in demonstrations read for training or prompting; the policy must
            tell the goal from the scene and its task. Off: the goal is observed, as in MT1/MT10/MT50.
        observation: ``state`` (the 39-d vector), ``pixels`` (the camera's picture as ``image`` instead) or
            ``pixels+state``. MuJoCo renders off-screen (EGL): slow on CPU, for short runs and tests.
        image_size: the picture's side in pixels (``pixels`` modes).
    """

    task: str = "reach"
    max_episode_steps: int = METAWORLD_HORIZON
    vector_strategy: Literal["sync", "async"] = "sync"
    eval_until_success: bool = False
    hidden_goal: bool = False
    observation: Literal["state", "pixels", "pixels+state"] = "state"
    image_size: int = 64

    def policy_observation(self, observation: torch.Tensor) -> torch.Tensor:
        """A stored 39-d observation as the policy sees it under these settings (the goal hidden or not)."""
        return hide_goal(observation) if self.hidden_goal else observation

    def validate(self) -> None:
        require(
            version_free(self.task) in MT50_TASKS,
            "task",
            f"unknown Meta-World task {self.task!r}; allowed: {', '.join(MT50_TASKS)}",
        )
        require(self.max_episode_steps >= 1, "max_episode_steps", f"must be >= 1 (got {self.max_episode_steps})")
        one_of(self.vector_strategy, VECTOR_STRATEGIES, "vector_strategy", "strategy")
        super().validate()
        check_pixel_settings(self)


def _metaworld_family(benchmark: str | Sequence[str], description: str, name: str | None = None) -> EnvFamily:
    def task_of(settings: MetaWorldSettings) -> str | None:
        return settings.task if benchmark == "MT1" else None

    def make(settings: MetaWorldSettings, request: EnvRequest) -> MetaWorldMultiTaskEnv:
        # Evaluation: one copy per task, its goal positions scheduled by the per-task evaluator.
        num_tasks = len(metaworld_task_set(benchmark, task_of(settings)))
        return MetaWorldMultiTaskEnv(
            benchmark,
            task_of(settings),
            use_one_hot=True,
            envs_per_task=1 if request.evaluation else max(1, request.num_envs // num_tasks),
            max_episode_steps=settings.max_episode_steps,
            seed=request.run_seed,
            device=request.device,
            vector_strategy=settings.vector_strategy,
            terminate_on_success=settings.eval_until_success and request.evaluation,
            hidden_goal=settings.hidden_goal,
            observation=settings.observation,
            image_size=settings.image_size,
        )

    def check(settings: MetaWorldSettings, run: Any) -> None:
        tasks = len(metaworld_task_set(benchmark, task_of(settings)))
        require(
            run.num_envs % tasks == 0,
            "num_envs",
            f"must be a multiple of the {tasks} tasks of {label} (one or more copies per task; got {run.num_envs})",
        )
        require(
            run.evaluation.eval_episodes <= METAWORLD_NUM_GOALS,
            "eval_episodes",
            f"Meta-World has {METAWORLD_NUM_GOALS} goal positions per task: at most {METAWORLD_NUM_GOALS} "
            f"episodes per task (got {run.evaluation.eval_episodes})",
        )

    def tasks_env(settings: MetaWorldSettings, request: EnvRequest, names: Sequence[str]) -> MetaWorldMultiTaskEnv:
        return MetaWorldMultiTaskEnv(
            list(names),
            max_episode_steps=settings.max_episode_steps,
            seed=request.run_seed,
            device=request.device,
            terminate_on_success=settings.eval_until_success,
            hidden_goal=settings.hidden_goal,
            observation=settings.observation,
            image_size=settings.image_size,
        )

    label = name.upper() if name else str(benchmark)
    family_name = name or str(benchmark).lower()
    every = "MT50" if family_name == "ml45" else benchmark  # ML45's demonstrations hold its test tasks too
    return EnvFamily(
        name=family_name,
        demos=lambda tasks: metaworld_demos(family_name, tasks or every),
        description=description,
        section="metaworld",
        tasks_env=tasks_env,
        task_sentences=lambda settings: {n: [d, *METAWORLD_PARAPHRASES.get(n, ())] for n, d in METAWORLD_DESCRIPTIONS.items()},
        settings=MetaWorldSettings,
        make=make,
        kind="multitask",
        actions="box",
        per_task_success="any",
        spec=lambda settings, request: metaworld_spec(
            benchmark, task_of(settings), settings.hidden_goal, settings.observation, settings.image_size
        ),
        video_env=lambda settings: MetaWorldVideoEnv(
            benchmark, task_of(settings), settings.max_episode_steps, hidden_goal=settings.hidden_goal
        ),
        check=check,
    )


def metaworld_demos(name: str, tasks: str | Sequence[str]) -> DemoSource:
    """Each task's scripted v3 expert from ``metaworld.policies`` (``ENV_POLICY_MAP``), goal positions resampled
    every episode; ``ml45``: all 50 tasks, with ML45's split (45 training, 5 test tasks) in the card."""
    task_set = metaworld_task_set(tasks)

    def make_env(names: Sequence[str], copies: int, seed: int, after_success: int, image_size: int = 0) -> BatchedEnv:
        camera = {"observation": "pixels+state", "image_size": image_size} if image_size else {}
        return MetaWorldMultiTaskEnv(
            list(names), envs_per_task=copies, seed=seed, terminate_on_success=True, success_hold=after_success, **camera
        )

    splits = {}
    if name == "ml45":
        splits = {"train": [n for n in task_set.names if n not in ML45_TEST_TASKS], "test": list(ML45_TEST_TASKS)}
    return DemoSource(name, task_set, make_env, metaworld_expert, "any", splits, cameras=True)


def metaworld_expert(env: Any) -> Expert:
    """The batched scripted experts of ``env``'s slots (``slot_tasks``)."""
    try:
        from metaworld.policies import ENV_POLICY_MAP
    except ImportError as error:
        raise ConfigError(
            "source", f"Meta-World experts need the `metaworld` extra: pip install 'taskrl[metaworld]' ({error})"
        ) from None

    names = env.task_set.names
    policies = [ENV_POLICY_MAP[metaworld_id(names[int(t)])]() for t in env.slot_tasks.tolist()]

    def act(obs: dict[str, torch.Tensor]) -> torch.Tensor:
        states = obs["observation"].detach().cpu().numpy().astype(np.float64)
        if getattr(env, "hidden_goal", False):  # the expert is told the goal the policy does not see
            states[:, METAWORLD_GOAL] = env.goals().cpu().numpy()
        with warnings.catch_warnings():  # the experts warn when their gains exceed the clipped range: noise
            warnings.filterwarnings("ignore", message="Constant\\(s\\) may be too high")
            actions = np.stack([p.get_action(s) for p, s in zip(policies, states)])
        return torch.as_tensor(np.clip(actions, -1.0, 1.0), dtype=torch.float32, device=env.device)

    return act


FAMILIES = (
    _metaworld_family("MT1", "Meta-World v3, one task (--task) with goal positions resampled every episode (metaworld extra)"),
    _metaworld_family("MT10", "Meta-World v3 MT10: ten manipulation tasks, the task index in the observation (metaworld extra)"),
    _metaworld_family("MT50", "Meta-World v3 MT50: fifty manipulation tasks (metaworld extra)"),
    _metaworld_family(
        ML45_TRAIN_TASKS,
        "Meta-World v3 ML45's 45 training tasks (its 5 test tasks held out: bin-picking, box-close, hand-insert, door-lock, door-unlock)",
        name="ml45",
    ),
)
