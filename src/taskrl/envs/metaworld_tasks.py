"""Meta-World v3 task sets (MT1, MT10, MT50, custom lists) as batched multi-task environments.

Needs the ``metaworld`` extra (``pip install 'taskrl[metaworld]'``, Meta-World 3.1.1 with MuJoCo
3.3.0); everything except `MetaWorldMultiTaskEnv` works without it.

- `METAWORLD_DESCRIPTIONS`: one human-written sentence for each of the 50 tasks, keyed by
  the version-free name (``reach``, ``pick-place``) in Meta-World's MT50 order; the metadata
  that language conditioning (CARE) embeds.
- `metaworld_task_set`: the [`TaskSet`][taskrl.tasks.TaskSet] of a benchmark.
- `MetaWorldMultiTaskEnv`: one vector slot per task (or ``envs_per_task``), observations
  ``{"observation": 39-d float32, "task": int64 index}``, ``info["is_success"]`` from Meta-World's
  ``info["success"]``, goal positions drawn afresh at every reset. It is a
  [`GymnasiumVectorEnv`][taskrl.envs.gymnasium_adapter.GymnasiumVectorEnv], so numpy becomes torch, autoreset
  and final observations are handled in that one place.
- the families ``mt1``, ``mt10`` and ``mt50`` (section ``metaworld``).

Meta-World's evaluation protocol (per task, episodes over distinct goal positions, success if
reached at any step) is [`taskrl.training.per_task.evaluate_per_task`][taskrl.training.per_task.evaluate_per_task].

Meta-World settings chosen (see ``docs/multitask.md``): ``use_one_hot`` always passed explicitly;
``task_select="random"`` so every reset picks one of the task's 50 pre-drawn goal positions
(``"pseudorandom"`` would keep one goal until ``sample_tasks()`` is called); Meta-World's reward
version ``"v2"`` (its default); horizon 500 (Meta-World's ``max_path_length``), configurable.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Sequence
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.base import BatchedEnv
from taskrl.envs.gymnasium_adapter import VECTOR_STRATEGIES, GymnasiumVectorEnv, VectorStrategy
from taskrl.envs.pixels import OBSERVATIONS, PixelObservation, check_pixel_settings
from taskrl.envs.spec import DemoSource, EnvFamily, EnvRequest, Expert
from taskrl.errors import ConfigError, one_of, require
from taskrl.tasks import TaskSet

__all__ = [
    "METAWORLD_DESCRIPTIONS",
    "METAWORLD_HORIZON",
    "METAWORLD_NUM_GOALS",
    "MT10_TASKS",
    "MT50_TASKS",
    "MetaWorldMultiTaskEnv",
    "metaworld_id",
    "metaworld_spec",
    "metaworld_task_set",
    "hide_goal",
    "version_free",
]

METAWORLD_VERSION = "v3"
METAWORLD_HORIZON = 500  # Meta-World's max_path_length
METAWORLD_NUM_GOALS = 50  # goal positions Meta-World pre-draws per task
METAWORLD_OBS_DIM = 39
METAWORLD_ACTION_DIM = 4
#: Where the goal position sits in the 39-d observation (Meta-World's ``_get_obs``: hand, gripper, objects,
#: the previous frame's 18, then the goal). ML benchmarks zero it (``_partially_observable``).
METAWORLD_GOAL = slice(36, 39)
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

#: Other wordings of the MT10 tasks and of ML45's test tasks, never seen in training: how robust a
#: language-conditioned policy is to how its task is said (``taskrl eval --held-out --prompt paraphrase``).
METAWORLD_PARAPHRASES: dict[str, tuple[str, ...]] = {
    "reach": ("Bring the robot's hand to the target.", "Put the end effector on the goal point."),
    "push": ("Slide the puck over the table until it reaches the target.", "Shove the small disc to the goal."),
    "pick-place": ("Grab the puck and set it down on the target.", "Lift the disc and put it where the goal is."),
    "door-open": ("Swing the door open.", "Open the door by pulling it around its hinge."),
    "drawer-open": ("Open the drawer.", "Grab the drawer handle and pull it out."),
    "drawer-close": ("Close the drawer.", "Shove the drawer back in."),
    "button-press-topdown": ("Push the button from the top.", "Press down on the button below the gripper."),
    "peg-insert-side": ("Grab the peg and push it into the hole from the side.", "Insert the peg horizontally into the slot."),
    "window-open": ("Open the window by sliding it.", "Push the window sideways to open it."),
    "window-close": ("Close the window by sliding it.", "Slide the window shut."),
    "bin-picking": (
        "Move the puck from the first bin into the second one.",
        "Take the disc out of its bin and drop it in the other.",
    ),
    "box-close": ("Put the lid on the box.", "Grab the cover and close the box with it."),
    "hand-insert": ("Put the gripper into the hole in the table.", "Lower the hand into the opening in the table top."),
    "door-lock": ("Lock the door by turning its lock down.", "Rotate the door's lock downwards."),
    "door-unlock": ("Unlock the door by turning its lock up.", "Rotate the door's lock upwards."),
}
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
#: Meta-World's ML45 split (its ``ML45_V3``): 5 test tasks, and the other 45 in MT50's order for training.
ML45_TEST_TASKS: tuple[str, ...] = ("bin-picking", "box-close", "hand-insert", "door-lock", "door-unlock")
ML45_TRAIN_TASKS: tuple[str, ...] = tuple(n for n in MT50_TASKS if n not in ML45_TEST_TASKS)


def hide_goal(observation: torch.Tensor) -> torch.Tensor:
    """The 39-d observation (``[..., 39]``) with the goal position zeroed, as Meta-World's ML benchmarks
    (``_partially_observable``) give it; a new tensor."""
    hidden = observation.clone()
    hidden[..., METAWORLD_GOAL] = 0.0
    return hidden


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
        raise ValueError(
            f"Meta-World task {name!r}: taskrl uses Meta-World {METAWORLD_VERSION}; write {base!r} or {metaworld_id(base)!r}"
        )
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
    """What an agent is built from — the task set and the spaces of `MetaWorldMultiTaskEnv` —
    without building the env (each task's MuJoCo model and goal draws take seconds), e.g. to load a
    trained agent. ``test_metaworld_tasks`` checks that it matches a real env."""

    task_set: TaskSet
    single_observation_space: gym.spaces.Dict
    single_action_space: gym.spaces.Box
    hidden_goal: bool = False

    def close(self) -> None:
        """Nothing to release (the same call as on an env)."""


def metaworld_spec(
    benchmark: str | Sequence[str] = "MT10",
    task: str | None = None,
    hidden_goal: bool = False,
    observation: str = "state",
    image_size: int = 64,
) -> MetaWorldSpec:
    """The `MetaWorldSpec` of a benchmark (arguments as `metaworld_task_set` and
    `MetaWorldMultiTaskEnv`)."""
    task_set = metaworld_task_set(benchmark, task)
    entries: dict[str, gym.spaces.Space] = {"task": gym.spaces.Discrete(len(task_set))}
    if observation != "pixels":
        entries = {"observation": gym.spaces.Box(-np.inf, np.inf, shape=(METAWORLD_OBS_DIM,), dtype=np.float32), **entries}
    if observation != "state":
        entries["image"] = gym.spaces.Box(0, 255, (image_size, image_size, 3), np.uint8)
    return MetaWorldSpec(
        task_set,
        gym.spaces.Dict(entries),
        gym.spaces.Box(-1.0, 1.0, shape=(METAWORLD_ACTION_DIM,), dtype=np.float32),
        hidden_goal,
    )


# ---------------------------------------------------------------------------------------------
# One Meta-World env per slot, with a dict observation and an optional goal schedule
# ---------------------------------------------------------------------------------------------
class MetaWorldTaskWrapper(gym.Wrapper):
    """One Meta-World env as ``{"observation": 39-d, "task": index}``, with an optional goal schedule.

    With ``use_one_hot``, the task index is read from Meta-World's one-hot (the last
    ``num_tasks`` entries of its observation) and checked against ``task_index``; otherwise it
    is ``task_index``. ``set_goal_schedules`` pins the goal positions of the next resets (used by
    [`evaluate_per_task`][taskrl.training.per_task.evaluate_per_task] to visit distinct goals); ``None`` restores random goals.
    With ``hidden_goal`` the goal position in the observation is zeroed (ML45's protocol); ``goal()`` still
    tells it (the scripted experts read it).
    """

    def __init__(
        self,
        env: gym.Env,
        slot: int,
        task_index: int,
        num_tasks: int,
        use_one_hot: bool,
        success_hold: int = 0,
        hidden_goal: bool = False,
    ) -> None:
        super().__init__(env)
        self.slot, self.task_index, self.num_tasks, self.use_one_hot = slot, task_index, num_tasks, use_one_hot
        self.hidden_goal = hidden_goal
        self._goal = np.zeros(3)
        self.success_hold = success_hold  # > 0: terminate this many steps after the first success
        self._since_success = -1
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
        observation = obs[:METAWORLD_OBS_DIM].copy()
        self._goal = observation[METAWORLD_GOAL].copy()
        if self.hidden_goal:
            observation[METAWORLD_GOAL] = 0.0
        return {"observation": observation, "task": np.int64(task)}

    def goal(self) -> np.ndarray:
        """The goal position of the last observation, hidden or not."""
        return self._goal

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
        self._since_success = -1
        return self._dict_obs(obs), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self.success_hold > 0:
            if self._since_success >= 0 or info.get("success", 0.0) >= 1.0:
                self._since_success += 1
            terminated = terminated or self._since_success >= self.success_hold
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
            out = {
                version_free(k): (cls, [t for t in bench.train_tasks if t.env_name == k])
                for k, cls in bench.train_classes.items()
            }
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


def _slot_kwargs(
    max_episode_steps: int, use_one_hot: bool = True, terminate_on_success: bool = False, reward_function_version: str = "v2"
) -> dict[str, Any]:
    """What Meta-World builds each slot's env with (``task_select="random"``: a new goal every reset)."""
    return {
        "max_episode_steps": max_episode_steps,
        "use_one_hot": use_one_hot,
        "terminate_on_success": terminate_on_success,
        "task_select": "random",
        "reward_function_version": reward_function_version,
    }


class _MetaWorldFactory:
    """Picklable zero-argument factory of one slot's env (async workers build their own)."""

    def __init__(
        self,
        slot: int,
        name: str,
        env_cls: type,
        goals: list,
        task_index: int,
        num_tasks: int,
        seed: int | None,
        kwargs: dict[str, Any],
        success_hold: int = 0,
        hidden_goal: bool = False,
        observation: str = "state",
        image_size: int = 64,
    ) -> None:
        self.slot, self.name, self.env_cls, self.goals = slot, name, env_cls, goals
        self.task_index, self.num_tasks, self.seed, self.kwargs = task_index, num_tasks, seed, kwargs
        self.success_hold, self.hidden_goal = success_hold, hidden_goal
        self.observation, self.image_size = observation, image_size
        self.__name__ = f"Meta-World/{name}"

    def __call__(self) -> gym.Env:
        import metaworld

        kwargs = self.kwargs
        if self.observation != "state":  # the camera renders at the picture's size, off-screen
            os.environ.setdefault("MUJOCO_GL", "egl")
            kwargs = {**kwargs, "render_mode": "rgb_array", "width": self.image_size, "height": self.image_size}
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
                **kwargs,
            )
        steps = self.kwargs["max_episode_steps"]
        if steps > env.unwrapped.max_path_length:  # Meta-World refuses steps past max_path_length
            env.unwrapped.max_path_length = steps
        wrapped = MetaWorldTaskWrapper(
            env, self.slot, self.task_index, self.num_tasks, self.kwargs["use_one_hot"], self.success_hold, self.hidden_goal
        )
        if self.observation == "state":
            return wrapped
        return PixelObservation(wrapped, self.image_size, keep_state=self.observation == "pixels+state")


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
        success_hold: with ``terminate_on_success``, end episodes this many steps after the first
            success instead (demonstrations then show the expert settling at the goal).
        reward_function_version: Meta-World's reward version, ``"v2"`` (its default) or ``"v1"``.
        num_goals: goal positions Meta-World pre-draws per task (its benchmarks: 50; fewer builds
            faster, e.g. in tests; Meta-World's ``make_vec(..., num_goals=n)`` does the same).
        hidden_goal: zero the goal position in observations, as Meta-World's ML benchmarks do (their
            ``_partially_observable``); the scripted experts still act on the true goal.
        observation: ``state``, ``pixels`` (the camera's picture as ``image`` instead of the 39-d state) or
            ``pixels+state`` (see ``envs/pixels.py``).
        image_size: the picture's side in pixels.
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
        success_hold: int = 0,
        hidden_goal: bool = False,
        observation: str = "state",
        image_size: int = 64,
        vector_kwargs: dict[str, Any] | None = None,
    ) -> None:
        self.task_set = metaworld_task_set(benchmark, task)
        self.hidden_goal = bool(hidden_goal)
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {', '.join(OBSERVATIONS)}, got {observation!r}")
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
        except ImportError:
            raise ConfigError("env", _INSTALL_HINT) from None
        self.use_one_hot = use_one_hot
        self.envs_per_task = envs_per_task
        if not isinstance(success_hold, int) or success_hold < 0:
            raise ValueError(f"success_hold must be an integer >= 0, got {success_hold!r}")
        hold = success_hold if terminate_on_success else 0
        kwargs = _slot_kwargs(max_episode_steps, use_one_hot, bool(terminate_on_success) and hold == 0, reward_function_version)
        num_tasks = len(self.task_set)
        goals = _benchmark_tasks(metaworld, benchmark, self.task_set.names, seed, num_goals)
        factories = [
            _MetaWorldFactory(
                t.index * envs_per_task + c,
                t.name,
                *goals[t.name],
                t.index,
                num_tasks,
                seed,
                kwargs,
                hold,
                self.hidden_goal,
                observation,
                image_size,
            )
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
        self.vector_env.call(
            "set_goal_schedules", None if schedules is None else [None if s is None else list(s) for s in schedules]
        )

    def goal_positions(self) -> int:
        """Goal positions per task (Meta-World draws 50)."""
        return int(min(self.vector_env.call("goal_positions")))

    def goals(self) -> torch.Tensor:
        """``[num_envs, 3]`` each slot's goal position now, also when the observation hides it."""
        return torch.as_tensor(np.stack(self.vector_env.call("goal")), dtype=torch.float32, device=self.device)


class MetaWorldVideoEnv(gym.Env):
    """One renderable copy of each task of a Meta-World benchmark, for videos (``taskrl eval --video``).

    ``reset(options={"task": k})`` picks task ``k`` (its copy is built on first use); observations are
    those of `MetaWorldMultiTaskEnv` (``observation`` and ``task``), frames come from MuJoCo.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 40}

    def __init__(
        self,
        benchmark: str | Sequence[str],
        task: str | None = None,
        max_episode_steps: int = METAWORLD_HORIZON,
        seed: int | None = 0,
        hidden_goal: bool = False,
    ) -> None:
        import metaworld

        self.task_set = metaworld_task_set(benchmark, task)
        goals = _benchmark_tasks(metaworld, benchmark, self.task_set.names, seed, METAWORLD_NUM_GOALS)
        kwargs = {**_slot_kwargs(max_episode_steps), "render_mode": "rgb_array"}
        n = len(self.task_set)
        self._factories = [
            _MetaWorldFactory(t.index, t.name, *goals[t.name], t.index, n, seed, kwargs, 0, hidden_goal) for t in self.task_set
        ]
        self._envs: dict[int, gym.Env] = {}
        self._current = 0
        spec = metaworld_spec(benchmark, task, hidden_goal)
        self.observation_space, self.action_space = spec.single_observation_space, spec.single_action_space
        self.render_mode = "rgb_array"

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        self._current = int((options or {}).get("task", 0))
        if self._current not in self._envs:
            self._envs[self._current] = self._factories[self._current]()
        return self._envs[self._current].reset(seed=seed)

    def step(self, action):
        return self._envs[self._current].step(action)

    def render(self):
        return self._envs[self._current].render()

    def close(self) -> None:
        for env in self._envs.values():
            env.close()
        self._envs.clear()


# ---------------------------------------------------------------------------------------------
# The families: mt1, mt10, mt50
# ---------------------------------------------------------------------------------------------
@dataclasses.dataclass
class MetaWorldSettings:
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
            run.eval_episodes <= METAWORLD_NUM_GOALS,
            "eval_episodes",
            f"Meta-World has {METAWORLD_NUM_GOALS} goal positions per task: at most {METAWORLD_NUM_GOALS} "
            f"episodes per task (got {run.eval_episodes})",
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
