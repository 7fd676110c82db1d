"""One Meta-World env per vector slot, with a dict observation and an optional goal schedule; the
batched multi-task env; the video env (needs the ``metaworld`` extra)."""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.gymnasium_adapter import GymnasiumVectorEnv, VectorStrategy
from taskrl.envs.meta_world.catalogue import (
    INSTALL_HINT,
    METAWORLD_GOAL,
    METAWORLD_HORIZON,
    METAWORLD_NUM_GOALS,
    METAWORLD_OBS_DIM,
    metaworld_id,
    metaworld_spec,
    metaworld_task_set,
    version_free,
)
from taskrl.envs.pixels import OBSERVATIONS, PixelObservation
from taskrl.errors import ConfigError


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
            raise ConfigError("env", INSTALL_HINT) from None
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
