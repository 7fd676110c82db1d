"""Meta-World v3 task sets (MT1, MT10, MT50, custom lists) as batched multi-task environments.

Needs the ``metaworld`` extra (``pip install 'taskrl[metaworld]'``, Meta-World 3.1.1 with MuJoCo
3.3.0); everything except :class:`MetaWorldMultiTaskEnv` works without it.

- :data:`METAWORLD_DESCRIPTIONS`: one human-written sentence for each of the 50 tasks, keyed by
  the version-free name (``reach``, ``pick-place``) in Meta-World's MT50 order; the metadata
  that language conditioning (CARE) embeds.
- :func:`metaworld_task_set`: the :class:`~taskrl.tasks.TaskSet` of a benchmark.
- :class:`MetaWorldMultiTaskEnv`: one vector slot per task (or ``envs_per_task``), observations
  ``{"observation": 39-d float32, "task": int64 index}``, ``info["is_success"]`` from Meta-World's
  ``info["success"]``, goal positions drawn afresh at every reset. It is a
  :class:`~taskrl.envs.gymnasium_adapter.GymnasiumVectorEnv`, so numpy becomes torch, autoreset
  and final observations are handled in that one place.
- :func:`evaluate_per_task`: Meta-World's protocol (per task, episodes over distinct goal
  positions, success if reached at any step; headline = mean over tasks), for any batched env
  whose observations carry ``task``.

Meta-World settings chosen (see ``docs/multitask.md``): ``use_one_hot`` always passed explicitly;
``task_select="random"`` so every reset picks one of the task's 50 pre-drawn goal positions
(``"pseudorandom"`` would keep one goal until ``sample_tasks()`` is called); Meta-World's reward
version ``"v2"`` (its default); horizon 500 (Meta-World's ``max_path_length``), configurable.
"""

from __future__ import annotations

import dataclasses
import json
import math
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.base import BatchedEnv, Obs
from taskrl.envs.gymnasium_adapter import GymnasiumVectorEnv, VectorStrategy
from taskrl.tasks import TaskSet

__all__ = [
    "METAWORLD_DESCRIPTIONS",
    "METAWORLD_HORIZON",
    "METAWORLD_NUM_GOALS",
    "MT10_TASKS",
    "MT50_TASKS",
    "MetaWorldMultiTaskEnv",
    "evaluate_per_task",
    "metaworld_id",
    "metaworld_spec",
    "metaworld_task_set",
    "per_task_table",
    "version_free",
]

METAWORLD_VERSION = "v3"
METAWORLD_HORIZON = 500  # Meta-World's max_path_length
METAWORLD_NUM_GOALS = 50  # goal positions Meta-World pre-draws per task
METAWORLD_OBS_DIM = 39
METAWORLD_ACTION_DIM = 4
_INSTALL_HINT = "Meta-World environments need the `metaworld` extra: pip install 'taskrl[metaworld]'"

# One sentence per task, written for taskrl from what each task asks of the robot (Yu et al.,
# 2019, appendix), in Meta-World's MT50 order (its ALL_V3_ENVIRONMENTS).
METAWORLD_DESCRIPTIONS: dict[str, str] = {
    "assembly": "Pick up the nut and fit it over the peg.",
    "basketball": "Pick up the ball and dunk it into the basket.",
    "bin-picking": "Pick the puck out of one bin and place it in the other bin.",
    "box-close": "Pick up the lid and put it on the box to close it.",
    "button-press-topdown": "Press the button down from above.",
    "button-press-topdown-wall": "Reach over a wall and press the button down from above.",
    "button-press": "Press the button in from the front.",
    "button-press-wall": "Reach around a wall and press the button in from the front.",
    "coffee-button": "Push the button on the coffee machine.",
    "coffee-pull": "Pull the mug out from under the coffee machine to the goal.",
    "coffee-push": "Push the mug under the coffee machine.",
    "dial-turn": "Turn the dial around to the goal angle.",
    "disassemble": "Pull the nut up and off the peg.",
    "door-close": "Push the open door closed on its hinge.",
    "door-lock": "Turn the lock on the door down to lock it.",
    "door-open": "Pull the door open on its hinge.",
    "door-unlock": "Turn the lock on the door up to unlock it.",
    "hand-insert": "Move the gripper into the hole in the table.",
    "drawer-close": "Push the drawer closed.",
    "drawer-open": "Pull the drawer open by its handle.",
    "faucet-open": "Turn the faucet handle to open the tap.",
    "faucet-close": "Turn the faucet handle the other way to close the tap.",
    "hammer": "Pick up the hammer and drive the nail into the wall.",
    "handle-press-side": "Press the handle down from the side.",
    "handle-press": "Press the handle down from the front.",
    "handle-pull-side": "Pull the handle up from the side.",
    "handle-pull": "Pull the handle up from the front.",
    "lever-pull": "Pull the lever up until it points to the goal.",
    "pick-place-wall": "Pick up the puck, carry it over a wall and place it at the goal.",
    "pick-out-of-hole": "Pick the puck up out of the hole and lift it to the goal.",
    "pick-place": "Pick up the puck and place it at the goal position.",
    "plate-slide": "Slide the plate forward into the cabinet.",
    "plate-slide-side": "Slide the plate sideways into the cabinet.",
    "plate-slide-back": "Slide the plate back out of the cabinet.",
    "plate-slide-back-side": "Slide the plate sideways back out of the cabinet.",
    "peg-insert-side": "Pick up the peg and insert it sideways into the hole.",
    "peg-unplug-side": "Pull the peg sideways out of its socket.",
    "soccer": "Push the soccer ball into the goal.",
    "stick-push": "Grasp the stick and use it to push the thermos to the goal.",
    "stick-pull": "Grasp the stick and use it to pull the thermos to the goal.",
    "push": "Push the puck across the table to the goal.",
    "push-wall": "Push the puck around a wall to the goal.",
    "push-back": "Pull the puck back towards the robot to the goal.",
    "reach": "Move the gripper to the goal position.",
    "reach-wall": "Move the gripper over a wall to the goal position.",
    "shelf-place": "Pick up the puck and place it on the shelf.",
    "sweep-into": "Sweep the puck into the hole in the table.",
    "sweep": "Sweep the puck off the edge of the table.",
    "window-open": "Slide the window open sideways.",
    "window-close": "Slide the window closed sideways.",
}

MT50_TASKS: tuple[str, ...] = tuple(METAWORLD_DESCRIPTIONS)
# Meta-World's MT10 order (the one-hot index of each task).
MT10_TASKS: tuple[str, ...] = (
    "reach",
    "push",
    "pick-place",
    "door-open",
    "drawer-open",
    "drawer-close",
    "button-press-topdown",
    "peg-insert-side",
    "window-open",
    "window-close",
)
BENCHMARKS = ("MT1", "MT10", "MT50")


def version_free(name: str) -> str:
    """``"reach-v3"`` -> ``"reach"`` (a name without a version suffix is returned as is)."""
    head, sep, tail = name.rpartition("-v")
    return head if sep and tail.isdigit() else name


def metaworld_id(name: str) -> str:
    """``"reach"`` -> ``"reach-v3"``, Meta-World's name of the task."""
    return f"{version_free(name)}-{METAWORLD_VERSION}"


def _check_name(name: str) -> str:
    if not isinstance(name, str):
        raise ValueError(f"a Meta-World task name must be a string, got {name!r}")
    base = version_free(name)
    if base not in METAWORLD_DESCRIPTIONS:
        raise ValueError(f"unknown Meta-World task {name!r}; allowed names: {', '.join(MT50_TASKS)}")
    if base != name and not name.endswith(f"-{METAWORLD_VERSION}"):
        raise ValueError(f"Meta-World task {name!r}: taskrl uses Meta-World {METAWORLD_VERSION}; write {base!r} or {metaworld_id(base)!r}")
    return base


def metaworld_task_set(benchmark: str | Sequence[str] = "MT10", task: str | None = None) -> TaskSet:
    """The task set of ``"MT1"`` (with ``task``), ``"MT10"``, ``"MT50"`` or a list of task names.

    Names may carry Meta-World's version suffix (``reach-v3``); the task set's names never do.
    The order is Meta-World's (MT10, MT50) or the list's, and fixes each task's index.
    """
    if isinstance(benchmark, str):
        if benchmark not in BENCHMARKS:
            raise ValueError(f"benchmark must be one of {', '.join(BENCHMARKS)} or a list of task names; got {benchmark!r}")
        if benchmark == "MT1":
            if task is None:
                raise ValueError(f"MT1 needs task=<name>; allowed names: {', '.join(MT50_TASKS)}")
            names: list[str] = [_check_name(task)]
        else:
            if task is not None:
                raise ValueError(f"task={task!r} applies to MT1 only (got benchmark={benchmark!r})")
            names = list(MT10_TASKS if benchmark == "MT10" else MT50_TASKS)
    else:
        if task is not None:
            raise ValueError("task applies to MT1 only; a custom benchmark is a list of task names")
        names = [_check_name(n) for n in benchmark]
        if not names:
            raise ValueError("a custom Meta-World benchmark needs at least one task name")
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            raise ValueError(f"a custom Meta-World benchmark lists tasks more than once: {', '.join(repeated)}")
    return TaskSet.from_pairs((n, METAWORLD_DESCRIPTIONS[n]) for n in names)


@dataclasses.dataclass
class MetaWorldSpec:
    """What an agent is built from — the task set and the spaces of :class:`MetaWorldMultiTaskEnv` —
    without building the env (each task's MuJoCo model and goal draws take seconds), e.g. to load a
    trained agent. ``test_metaworld_tasks`` checks that it matches a real env."""

    task_set: TaskSet
    single_observation_space: gym.spaces.Dict
    single_action_space: gym.spaces.Box

    def close(self) -> None:
        """Nothing to release (the same call as on an env)."""


def metaworld_spec(benchmark: str | Sequence[str] = "MT10", task: str | None = None) -> MetaWorldSpec:
    """The :class:`MetaWorldSpec` of a benchmark (arguments as :func:`metaworld_task_set`)."""
    task_set = metaworld_task_set(benchmark, task)
    observation = gym.spaces.Box(-np.inf, np.inf, shape=(METAWORLD_OBS_DIM,), dtype=np.float32)
    return MetaWorldSpec(task_set, gym.spaces.Dict({"observation": observation, "task": gym.spaces.Discrete(len(task_set))}),
                         gym.spaces.Box(-1.0, 1.0, shape=(METAWORLD_ACTION_DIM,), dtype=np.float32))


# ---------------------------------------------------------------------------------------------
# One Meta-World env per slot, with a dict observation and an optional goal schedule
# ---------------------------------------------------------------------------------------------
class MetaWorldTaskWrapper(gym.Wrapper):
    """One Meta-World env as ``{"observation": 39-d, "task": index}``, with an optional goal schedule.

    With ``use_one_hot``, the task index is read from Meta-World's one-hot (the last
    ``num_tasks`` entries of its observation) and checked against ``task_index``; otherwise it
    is ``task_index``. ``set_goal_schedules`` pins the goal positions of the next resets (used by
    :func:`evaluate_per_task` to visit distinct goals); ``None`` restores random goals.
    """

    def __init__(self, env: gym.Env, slot: int, task_index: int, num_tasks: int, use_one_hot: bool) -> None:
        super().__init__(env)
        self.slot, self.task_index, self.num_tasks, self.use_one_hot = slot, task_index, num_tasks, use_one_hot
        space = env.observation_space
        expected = METAWORLD_OBS_DIM + (num_tasks if use_one_hot else 0)
        if not isinstance(space, gym.spaces.Box) or space.shape != (expected,):
            raise ValueError(f"Meta-World observation space: expected Box of shape ({expected},), got {space}")
        # Unbounded: the tasks' own bounds differ (goal space), and vector envs need equal spaces.
        box = gym.spaces.Box(-np.inf, np.inf, shape=(METAWORLD_OBS_DIM,), dtype=space.dtype)
        self.observation_space = gym.spaces.Dict({"observation": box, "task": gym.spaces.Discrete(num_tasks)})
        self._schedule: list[int] | None = None
        self._next = 0

    def _dict_obs(self, obs: np.ndarray) -> dict[str, Any]:
        task = self.task_index
        if self.use_one_hot:
            one_hot = obs[METAWORLD_OBS_DIM:]
            task = int(np.argmax(one_hot))
            if task != self.task_index or one_hot[task] != 1.0 or one_hot.sum() != 1.0:
                raise RuntimeError(f"Meta-World one-hot {one_hot.tolist()} does not encode task index {self.task_index}")
        return {"observation": obs[:METAWORLD_OBS_DIM], "task": np.int64(task)}

    def goal_positions(self) -> int:
        """How many pre-drawn goal positions this task has."""
        return len(self.env.get_wrapper_attr("tasks"))

    def set_goal_schedules(self, schedules: Sequence[Sequence[int] | None] | None) -> None:
        """``schedules[slot]``: goal indices for this slot's next resets, in order (cycled)."""
        schedule = None if schedules is None else schedules[self.slot]
        toggle = self.env.get_wrapper_attr("toggle_sample_tasks_on_reset")
        if schedule is None:
            self._schedule = None
            toggle(True)
            return
        n = self.goal_positions()
        schedule = [int(g) for g in schedule]
        if not schedule or any(not 0 <= g < n for g in schedule):
            raise ValueError(f"goal schedule of slot {self.slot} must be indices in 0..{n - 1}; got {schedule}")
        self._schedule, self._next = schedule, 0
        toggle(False)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:  # Meta-World's reset ignores its seed: seed the goal choice here
            self.env.unwrapped.seed(seed)
        if self._schedule is not None:
            goal = self._schedule[self._next % len(self._schedule)]
            self._next += 1
            self.env.unwrapped.set_task(self.env.get_wrapper_attr("tasks")[goal])
        obs, info = self.env.reset(seed=seed, options=options)
        return self._dict_obs(obs), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._dict_obs(obs), reward, terminated, truncated, info


def _benchmark_tasks(
    metaworld: Any, benchmark: str | Sequence[str], names: list[str], seed: int | None, num_goals: int
) -> dict[str, tuple[type, list]]:
    """``{name: (env class, its goal tasks)}``, drawn as Meta-World's own constructors draw them.

    MT10 / MT50 build Meta-World's benchmark object (all tasks' goals from one seeded stream, as
    ``gymnasium.make_vec("Meta-World/MT10", seed=seed)``); MT1 and custom lists build ``MT1`` per
    task (the goals of ``gymnasium.make("Meta-World/MT1", env_name=..., seed=seed)``). ``num_goals``
    goal positions per task (Meta-World: 50).
    """
    saved = metaworld._N_GOALS  # Meta-World's own num_goals option sets this module global too
    metaworld._N_GOALS = num_goals
    try:
        if isinstance(benchmark, str) and benchmark in ("MT10", "MT50"):
            bench = getattr(metaworld, benchmark)(seed=seed)
            out = {version_free(k): (cls, [t for t in bench.train_tasks if t.env_name == k]) for k, cls in bench.train_classes.items()}
            if list(out) != names:  # the hard-coded order is the one-hot order: it must be Meta-World's
                raise RuntimeError(f"Meta-World's {benchmark} tasks {list(out)} differ from taskrl's {names}")
            return out
        out = {}
        for name in names:
            bench = metaworld.MT1(metaworld_id(name), seed=seed)
            out[name] = (bench.train_classes[metaworld_id(name)], list(bench.train_tasks))
        return out
    finally:
        metaworld._N_GOALS = saved


class _MetaWorldFactory:
    """Picklable zero-argument factory of one slot's env (async workers build their own)."""

    def __init__(self, slot: int, name: str, env_cls: type, goals: list, task_index: int, num_tasks: int,
                 seed: int | None, kwargs: dict[str, Any]) -> None:
        self.slot, self.name, self.env_cls, self.goals = slot, name, env_cls, goals
        self.task_index, self.num_tasks, self.seed, self.kwargs = task_index, num_tasks, seed, kwargs
        self.__name__ = f"Meta-World/{name}"

    def __call__(self) -> gym.Env:
        import metaworld

        # What Meta-World's own MT constructors call for each vector slot. Its float64 space
        # bounds make gymnasium warn about casting them to float32 on every construction: noise.
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*precision lowered by casting to float32.*")
            env = metaworld._init_each_env(
                env_cls=self.env_cls,
                tasks=self.goals,
                seed=self.seed,
                env_id=self.task_index,
                num_tasks=self.num_tasks,
                **self.kwargs,
            )
        steps = self.kwargs["max_episode_steps"]
        if steps > env.unwrapped.max_path_length:  # Meta-World refuses steps past max_path_length
            env.unwrapped.max_path_length = steps
        return MetaWorldTaskWrapper(env, self.slot, self.task_index, self.num_tasks, self.kwargs["use_one_hot"])


class MetaWorldMultiTaskEnv(GymnasiumVectorEnv):
    """A batched Meta-World v3 multi-task environment: ``envs_per_task`` slots per task.

    Slots are task-major: slot ``s`` runs task ``s // envs_per_task`` (``slot_tasks``).

    Args:
        benchmark: ``"MT1"`` (with ``task``), ``"MT10"``, ``"MT50"`` or a list of task names.
        task: the task of MT1 (``"reach"`` or ``"reach-v3"``).
        use_one_hot: passed to Meta-World as is (its default is False). When True, the
            observation's ``task`` index is read back from Meta-World's one-hot (and checked);
            either way the 39-d ``observation`` excludes it: a task encoder makes the one-hot
            from ``task``.
        envs_per_task: slots per task.
        max_episode_steps: horizon (Meta-World's is 500).
        seed: seed of Meta-World's goal positions, drawn as Meta-World's own constructors draw
            them: MT10 / MT50 give the goals of ``gymnasium.make_vec("Meta-World/MT10", seed=seed)``,
            MT1 and custom lists those of ``Meta-World/MT1`` for each task. Also the seed of every
            slot's goal choice; ``reset(seed)`` reseeds slot ``i``'s choice with ``seed + i``
            (Meta-World's own ``reset`` ignores its seed).
        device: torch device of every returned tensor.
        vector_strategy: ``"sync"`` or ``"async"`` (a process per slot).
        terminate_on_success: end episodes at the first success (Meta-World's default: no).
        reward_function_version: Meta-World's reward version, ``"v2"`` (its default) or ``"v1"``.
        num_goals: goal positions Meta-World pre-draws per task (its benchmarks: 50; fewer builds
            faster, e.g. in tests; Meta-World's ``make_vec(..., num_goals=n)`` does the same).
        vector_kwargs: extra keyword arguments of the gymnasium vector env.

    Attributes:
        task_set: the tasks, in index order.
        slot_tasks: ``[num_envs]`` long tensor, the task index of each slot.
    """

    def __init__(
        self,
        benchmark: str | Sequence[str] = "MT10",
        task: str | None = None,
        *,
        use_one_hot: bool = True,
        envs_per_task: int = 1,
        max_episode_steps: int = METAWORLD_HORIZON,
        seed: int | None = 0,
        device: str | torch.device = "cpu",
        vector_strategy: VectorStrategy = "sync",
        terminate_on_success: bool = False,
        reward_function_version: Literal["v1", "v2"] = "v2",
        num_goals: int = METAWORLD_NUM_GOALS,
        vector_kwargs: dict[str, Any] | None = None,
    ) -> None:
        self.task_set = metaworld_task_set(benchmark, task)
        if not isinstance(use_one_hot, bool):
            raise ValueError(f"use_one_hot must be True or False, got {use_one_hot!r}")
        if not isinstance(envs_per_task, int) or envs_per_task < 1:
            raise ValueError(f"envs_per_task must be an integer >= 1, got {envs_per_task!r}")
        if not isinstance(max_episode_steps, int) or max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be an integer >= 1, got {max_episode_steps!r}")
        if reward_function_version not in ("v1", "v2"):
            raise ValueError(f"reward_function_version must be 'v1' or 'v2', got {reward_function_version!r}")
        if not isinstance(num_goals, int) or num_goals < 1:
            raise ValueError(f"num_goals must be an integer >= 1, got {num_goals!r}")
        try:
            import metaworld
        except ImportError as e:
            raise ImportError(_INSTALL_HINT) from e
        self.use_one_hot = use_one_hot
        self.envs_per_task = envs_per_task
        kwargs = {
            "max_episode_steps": max_episode_steps,
            "use_one_hot": use_one_hot,
            "terminate_on_success": bool(terminate_on_success),
            "task_select": "random",
            "reward_function_version": reward_function_version,
        }
        num_tasks = len(self.task_set)
        goals = _benchmark_tasks(metaworld, benchmark, self.task_set.names, seed, num_goals)
        factories = [
            _MetaWorldFactory(t.index * envs_per_task + c, t.name, *goals[t.name], t.index, num_tasks, seed, kwargs)
            for t in self.task_set
            for c in range(envs_per_task)
        ]
        super().__init__(
            factories,
            device=device,
            vector_strategy=vector_strategy,
            success_key="success",
            max_episode_steps=max_episode_steps,
            vector_kwargs=vector_kwargs,
        )
        self.env_id = f"Meta-World/{'+'.join(self.task_set.names) if num_tasks <= 3 else benchmark}"
        self.slot_tasks = torch.arange(self.num_envs, device=self.device) // envs_per_task

    def set_goal_schedules(self, schedules: Sequence[Sequence[int] | None] | None) -> None:
        """Pin each slot's goal positions for its next resets (``None``: random goals again)."""
        if schedules is not None and len(schedules) != self.num_envs:
            raise ValueError(f"need one goal schedule per slot ({self.num_envs}), got {len(schedules)}")
        self.vector_env.call("set_goal_schedules", None if schedules is None else [None if s is None else list(s) for s in schedules])

    def goal_positions(self) -> int:
        """Goal positions per task (Meta-World draws 50)."""
        return int(min(self.vector_env.call("goal_positions")))


# ---------------------------------------------------------------------------------------------
# Evaluation: Meta-World's protocol, per task
# ---------------------------------------------------------------------------------------------
@torch.no_grad()
def evaluate_per_task(
    policy: Callable[[Obs], torch.Tensor],
    env: BatchedEnv | Callable[[], BatchedEnv],
    episodes_per_task: int = METAWORLD_NUM_GOALS,
    seed: int = 0,
    task_set: TaskSet | None = None,
    console: Any = None,
    save_to: str | Path | None = None,
    max_steps: int | None = None,
    success: Literal["any", "final"] = "any",
) -> dict[str, Any]:
    """Per-task success following Meta-World's protocol; the headline is the mean over tasks.

    For each task, ``episodes_per_task`` episodes are run (over distinct goal positions where
    the env can pin them, as :class:`MetaWorldMultiTaskEnv` does: episode ``j`` of a task uses
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
        console: a ``rich`` console to print the table on (``None``: no printing).
        save_to: write the result as JSON to this path.
        max_steps: safety cap on env steps (default: generous, from the horizon).
        success: ``"any"`` (Meta-World: reached at any step of the episode) or ``"final"``
            (``is_success`` at the step the episode ends, as :func:`taskrl.training.evaluation.evaluate`).

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
        return _evaluate_per_task(policy, env, episodes_per_task, seed, task_set, console, save_to, max_steps, success)
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


def _evaluate_per_task(policy, env, n, seed, task_set, console, save_to, max_steps, criterion) -> dict[str, Any]:
    task_set = task_set if task_set is not None else getattr(env, "task_set", None)
    if task_set is None:
        raise ValueError("evaluate_per_task needs the env's task_set (env.task_set) or task_set=...")
    if "task" not in env.single_observation_space.spaces:
        raise ValueError(f"evaluate_per_task needs observations with a 'task' key; found {list(env.single_observation_space.spaces)}")
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
                raise ValueError(f"episodes_per_task={n} exceeds the {available} distinct goal positions per task")
            env.set_goal_schedules([g or None for g in goals])
            pinned = True
    if max_steps is None:
        rounds = math.ceil(n * num_tasks / num_envs) if quotas is None else int(quotas.max())
        max_steps = env.horizon * (rounds + 1) * (1 if quotas is not None else 20)

    successes = torch.zeros(num_tasks, dtype=torch.long)
    episodes = torch.zeros(num_tasks, dtype=torch.long)
    returns = torch.zeros(num_tasks, dtype=torch.float64)
    lengths = torch.zeros(num_tasks, dtype=torch.float64)
    done_slot = torch.zeros(num_envs, dtype=torch.long)  # episodes recorded per slot
    try:
        obs = env.reset(seed=seed)
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
    if console is not None:
        console.print(per_task_table(result))
    if save_to is not None:
        path = Path(save_to)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(path.suffix + ".tmp")
        tmp.write_text(json.dumps(result, indent=2) + "\n")
        tmp.replace(path)
    return result


def per_task_table(result: dict[str, Any], title: str = "per-task success"):
    """A ``rich`` table of :func:`evaluate_per_task`'s result, with the mean over tasks last."""
    from rich.table import Table

    table = Table(title=title)
    table.add_column("#", justify="right")
    table.add_column("task")
    table.add_column("success", justify="right")
    table.add_column("episodes", justify="right")
    table.add_column("return", justify="right")
    for name, row in result["tasks"].items():
        table.add_row(str(row["index"]), name, f"{row['success_rate']:.2f}", str(row["episodes"]), f"{row['mean_return']:.1f}")
    table.add_section()
    table.add_row("", "[bold]mean over tasks", f"[bold]{result['mean_success_rate']:.3f}", "", "")
    return table
