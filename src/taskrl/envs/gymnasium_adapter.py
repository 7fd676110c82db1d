"""Gymnasium environments (Fetch, Meta-World, ``taskrl/PointReach-v0``, a user's own) as batched envs.

`GymnasiumVectorEnv` runs ``num_envs`` copies of any gymnasium env with ``Dict`` or ``Box``
observations through gymnasium's vector API (sync or async) with same-step autoreset, and is the
only place where gymnasium's numpy data becomes torch tensors. `GymnasiumGoalEnv` adds the
goal-env part (``achieved_goal`` / ``desired_goal`` and the goal functions).

- observations: dict of numpy batches -> dict of tensors on ``device`` (float64 keys become
  float32 by default, and ``single_observation_space`` says so, so replay storage agrees); a
  plain ``Box`` observation becomes the ``observation`` key of a one-key dict;
- autoreset: gymnasium puts the final observation of each finished episode in
  ``info["final_obs"]`` (an object array of per-env dicts, masked by ``info["_final_obs"]``) and
  the finished step's info in ``info["final_info"]``; the adapter returns ``info["final_obs"]``
  as a dict of tensors for every env (equal to the returned observation where nothing ended);
- success: ``info["is_success"]`` is a bool tensor read from the env's ``success_key`` of the
  step that was taken (from ``final_info`` where the episode ended, never from the reset info);
- goal functions: ``compute_reward`` / ``compute_terminated`` take torch batches, call the
  single env's numpy function (vectorised in gymnasium-robotics) and convert back.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Any, Literal

import gymnasium as gym
import numpy as np
import torch

from taskrl.envs.base import BatchedEnv, GoalEnvMixin, Obs, StepResult

VectorStrategy = Literal["sync", "async"]
VECTOR_STRATEGIES = ("sync", "async")
#: ``success_key="auto"`` reads the first of these that the env's step info has (else: never a success).
AUTO_SUCCESS_KEYS = ("is_success", "success")


def _ensure_registered(env_id: str) -> None:
    """Make ``env_id`` known to gymnasium: taskrl's own ids and gymnasium-robotics' (if installed)."""
    if env_id in gym.registry or ":" in env_id:
        return
    if env_id.startswith("taskrl/"):
        from taskrl.registration import register_gymnasium_envs

        register_gymnasium_envs()
        return
    try:
        import gymnasium_robotics
    except ImportError:
        return
    gym.register_envs(gymnasium_robotics)


def _make_env(env_id: str, env_kwargs: dict[str, Any], max_episode_steps: int | None) -> gym.Env:
    """Module-level (picklable) factory, so async workers started by spawn can build the env."""
    _ensure_registered(env_id)
    if max_episode_steps is not None:
        return gym.make(env_id, max_episode_steps=max_episode_steps, **env_kwargs)
    return gym.make(env_id, **env_kwargs)


def _in_worker(factory: Callable[[], gym.Env]) -> gym.Env:
    """Build a copy in an async worker process that ignores Ctrl-C and SIGTERM: a terminal sends
    them to every process of the run, and the run stops cleanly (evaluation, checkpoint) only if its
    workers live until it closes them."""
    import multiprocessing
    import signal

    if multiprocessing.parent_process() is not None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return factory()


def _with_time_limit(factory: Callable[[], gym.Env], max_episode_steps: int) -> gym.Env:
    return gym.wrappers.TimeLimit(factory(), max_episode_steps=max_episode_steps)


def _convert_space(space: gym.spaces.Space, dtype: torch.dtype | None) -> gym.spaces.Space:
    """A floating ``Box`` in the observation dtype; every other space unchanged."""
    if dtype is None or not isinstance(space, gym.spaces.Box) or not np.issubdtype(space.dtype, np.floating):
        return space
    np_dtype = torch.empty((), dtype=dtype).numpy().dtype
    return gym.spaces.Box(space.low.astype(np_dtype), space.high.astype(np_dtype), shape=space.shape, dtype=np_dtype)


def _never_terminates(env: gym.Env) -> bool:
    """True for gymnasium-robotics' robot envs (Fetch, Shadow hand), whose ``compute_terminated``
    is the library's constant ``False`` (continuing tasks): no need to call it row by row."""
    try:
        from gymnasium_robotics.envs.robot_env import BaseRobotEnv
    except ImportError:
        return False
    return getattr(type(env), "compute_terminated", None) is BaseRobotEnv.compute_terminated


def _torch_dtype(space: gym.spaces.Space) -> torch.dtype:
    return torch.from_numpy(np.zeros((), dtype=space.dtype)).dtype


EnvFactory = Callable[[], gym.Env]


class GymnasiumVectorEnv(BatchedEnv):
    """``num_envs`` copies of a gymnasium env with ``Dict`` observations behind the batched contract.

    Args:
        env: a registered id (``"FetchReach-v4"``, ``"taskrl/PointReach-v0"``; gymnasium-robotics
            ids are registered on demand when it is installed), a zero-argument factory
            returning a ``gymnasium.Env``, or a sequence of such factories, one per copy (copies
            may then differ, e.g. one Meta-World task per copy).
        num_envs: copies stepped in parallel (default 1, or one per factory of a sequence).
        device: torch device of every returned tensor.
        vector_strategy: ``"sync"`` (one process, ``SyncVectorEnv``) or ``"async"``
            (a worker process per copy, ``AsyncVectorEnv``).
        success_key: info key of per-step success (``"is_success"`` for Fetch and taskrl,
            ``"success"`` for Meta-World); ``"auto"``: whichever of those the info has (always
            False if neither); ``None`` reports no success (always False).
        max_episode_steps: time limit; default the env spec's ``max_episode_steps``. It is
            also ``horizon`` (None where neither is given: the env ends its own episodes).
        observation_dtype: floating observation keys are converted to this dtype (``None``
            keeps the env's, e.g. float64 for Fetch).
        env_kwargs: keyword arguments of ``gymnasium.make`` (only with a registered id).
        vector_kwargs: extra keyword arguments of the vector env (e.g. ``context="spawn"``).

    Seeding: ``reset(seed)`` seeds copy ``i`` with ``seed + i`` (gymnasium's convention).
    Actions are passed to the env as given (no clipping), in the action space's dtype.
    """

    # Goal envs keep one local instance beside async workers (their goal functions run here).
    _needs_local_env = False

    def __init__(
        self,
        env: str | EnvFactory | Sequence[EnvFactory],
        num_envs: int | None = None,
        device: str | torch.device = "cpu",
        vector_strategy: VectorStrategy = "sync",
        success_key: str | None = "is_success",
        max_episode_steps: int | None = None,
        observation_dtype: torch.dtype | None = torch.float32,
        env_kwargs: dict[str, Any] | None = None,
        vector_kwargs: dict[str, Any] | None = None,
    ) -> None:
        if num_envs is not None and (not isinstance(num_envs, int) or num_envs < 1):
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if vector_strategy not in VECTOR_STRATEGIES:
            raise ValueError(f"vector_strategy must be one of {', '.join(VECTOR_STRATEGIES)}; got {vector_strategy!r}")
        if max_episode_steps is not None and (not isinstance(max_episode_steps, int) or max_episode_steps < 1):
            raise ValueError(f"max_episode_steps must be an integer >= 1, got {max_episode_steps!r}")
        if observation_dtype is not None and not observation_dtype.is_floating_point:
            raise ValueError(f"observation_dtype must be a floating torch dtype or None, got {observation_dtype!r}")
        autoreset = getattr(gym.vector, "AutoresetMode", None)
        if autoreset is None:
            raise RuntimeError(f"{type(self).__name__} needs gymnasium >= 1.1 (same-step autoreset); found {gym.__version__}")

        factories: list[EnvFactory]
        if isinstance(env, str):
            _ensure_registered(env)
            if ":" not in env and env not in gym.registry:
                raise ValueError(
                    f"env {env!r} is not registered with gymnasium; Fetch tasks need gymnasium-robotics "
                    f"(pip install 'taskrl[robotics]')"
                )
            self.env_id = env
            num_envs = num_envs or 1
            factories = [functools.partial(_make_env, env, dict(env_kwargs or {}), max_episode_steps)] * num_envs
        elif callable(env) or (isinstance(env, Sequence) and len(env) > 0 and all(callable(f) for f in env)):
            if env_kwargs:
                raise ValueError("env_kwargs applies to a registered env id, not to an env factory")
            if callable(env):
                num_envs = num_envs or 1
                factories = [env] * num_envs
            else:
                if num_envs is not None and num_envs != len(env):
                    raise ValueError(f"num_envs ({num_envs}) must equal the number of env factories ({len(env)})")
                num_envs, factories = len(env), list(env)
            self.env_id = getattr(factories[0], "__name__", repr(factories[0]))
            if max_episode_steps is not None:
                factories = [functools.partial(_with_time_limit, f, max_episode_steps) for f in factories]
        else:
            raise ValueError(
                f"env must be a registered gymnasium id, a factory of gymnasium.Env or a sequence of factories, got {env!r}"
            )

        self.num_envs = num_envs
        self.device = torch.device(device)
        self.success_key = success_key
        self.vector_strategy = vector_strategy
        vector_cls = gym.vector.SyncVectorEnv if vector_strategy == "sync" else gym.vector.AsyncVectorEnv
        if vector_strategy == "async":
            factories = [functools.partial(_in_worker, f) for f in factories]
        # An in-process env: copy 0 with "sync"; with "async", one extra local instance if needed.
        self._local: gym.Env | None = None
        if vector_strategy == "async" and self._needs_local_env:
            self._local = factories[0]()
            try:
                self._check_env(self._local.observation_space, self._local.unwrapped)
            except ValueError:
                self._local.close()
                raise
        self.vector_env = vector_cls(factories, autoreset_mode=autoreset.SAME_STEP, **(vector_kwargs or {}))
        first = self._local if self._local is not None else getattr(self.vector_env, "envs", [None])[0]
        self.first_env: gym.Env | None = first.unwrapped if first is not None else None
        try:
            self._check_env(self.vector_env.single_observation_space, self.first_env)
            if self.vector_env.metadata.get("autoreset_mode") != autoreset.SAME_STEP:
                raise RuntimeError(f"the vector env does not use same-step autoreset: {self.vector_env.metadata!r}")
            # None: the env ends its own episodes (the replay discovers their lengths)
            self.horizon = max_episode_steps if max_episode_steps is not None else self._spec_steps(first)
        except Exception:
            self.close()
            raise

        raw_space = self.vector_env.single_observation_space
        self._wrap_obs = not isinstance(raw_space, gym.spaces.Dict)  # a Box: the "observation" key
        raw_spaces = {"observation": raw_space} if self._wrap_obs else raw_space.spaces
        self.single_observation_space = gym.spaces.Dict({k: _convert_space(s, observation_dtype) for k, s in raw_spaces.items()})
        self.single_action_space = self.vector_env.single_action_space
        self._obs_dtypes = {k: _torch_dtype(s) for k, s in self.single_observation_space.spaces.items()}
        self._action_shape = self.vector_env.action_space.shape
        self._action_dtype = self.single_action_space.dtype

    def _spec_steps(self, first: gym.Env | None) -> int | None:
        if first is not None:
            spec = first.spec
        else:  # async without a local instance: ask copy 0
            try:
                spec = self.vector_env.get_attr("spec")[0]
            except Exception:
                spec = None
        return spec.max_episode_steps if spec is not None else None

    def _check_env(self, space: gym.spaces.Space, unwrapped: gym.Env | None) -> None:
        """Raise a ``ValueError`` when the env does not fit: observations must be a ``Box`` or a
        ``Dict`` of ``Box`` / ``Discrete`` entries (what the networks read)."""
        entries = space.spaces if isinstance(space, gym.spaces.Dict) else {"observation": space}
        bad = {k: type(s).__name__ for k, s in entries.items() if not isinstance(s, (gym.spaces.Box, gym.spaces.Discrete))}
        if bad or (not isinstance(space, gym.spaces.Dict) and not isinstance(space, gym.spaces.Box)):
            raise ValueError(
                f"env {self.env_id!r} has observation space {space}: taskrl reads a Box, or a Dict of Box "
                f"(and Discrete task index) entries; wrap it, e.g. with gymnasium.wrappers.FlattenObservation"
            )

    # ---------------------------------------------------------------- conversion
    def _as_dict(self, obs: dict[str, np.ndarray] | np.ndarray) -> dict[str, np.ndarray]:
        """A plain Box observation as the ``observation`` key; a dict as it is."""
        return {"observation": obs} if self._wrap_obs else obs

    def _to_torch(self, obs: dict[str, np.ndarray]) -> Obs:
        # torch.tensor copies: returned tensors never alias gymnasium's buffers or each other.
        return {k: torch.tensor(obs[k], dtype=dtype, device=self.device) for k, dtype in self._obs_dtypes.items()}

    def _to_numpy(self, x: torch.Tensor | np.ndarray) -> np.ndarray:
        return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)

    def _final_obs(self, obs: dict[str, np.ndarray], info: dict[str, Any]) -> dict[str, np.ndarray]:
        """The returned observations with each finished env's row replaced by its final one."""
        ended = info.get("_final_obs")
        if ended is None or not ended.any():
            return obs
        final = {k: np.array(obs[k], copy=True) for k in self._obs_dtypes}
        for i in np.flatnonzero(ended):
            last = self._as_dict(info["final_obs"][i])
            for k in final:
                final[k][i] = last[k]
        return final

    def _success(self, info: dict[str, Any], ended: np.ndarray) -> np.ndarray:
        success = np.zeros(self.num_envs, dtype=bool)
        key = self.success_key
        if key == "auto":
            final_info = info.get("final_info") or {}
            key = next((k for k in AUTO_SUCCESS_KEYS if k in info or k in final_info), None)
        if key is None:
            return success
        seen = np.zeros(self.num_envs, dtype=bool)
        if key in info:  # envs that did not end: this step's info (ended envs: the reset info, skipped)
            mask = info.get(f"_{key}", np.ones(self.num_envs, dtype=bool)) & ~ended
            success[mask] = np.asarray(info[key])[mask].astype(bool)
            seen |= mask
        final_info = info.get("final_info")
        if final_info is not None and key in final_info:  # envs that ended: their last step's info
            mask = final_info.get(f"_{key}", np.ones(self.num_envs, dtype=bool)) & info["_final_info"]
            success[mask] = np.asarray(final_info[key])[mask].astype(bool)
            seen |= mask
        if not seen.any():
            found = sorted(k for k in info if not k.startswith("_"))
            raise ValueError(
                f"success_key={key!r} is not in the step info of {self.env_id!r} (keys: {found}); "
                f"set success_key (Meta-World: 'success') or None"
            )
        return success

    # ---------------------------------------------------------------- batched contract
    def reset(self, seed: int | None = None) -> Obs:
        obs, _ = self.vector_env.reset(seed=seed)
        return self._to_torch(self._as_dict(obs))

    def step(self, action: torch.Tensor) -> StepResult:
        action_np = np.asarray(self._to_numpy(action), dtype=self._action_dtype).reshape(self._action_shape)
        obs, reward, terminated, truncated, info = self.vector_env.step(action_np)
        obs = self._as_dict(obs)
        ended = np.logical_or(terminated, truncated)
        out = {
            "final_obs": self._to_torch(self._final_obs(obs, info)),
            "is_success": torch.from_numpy(self._success(info, ended)).to(self.device),
        }
        return (
            self._to_torch(obs),
            torch.as_tensor(reward, dtype=torch.float32).to(self.device),
            torch.as_tensor(terminated, dtype=torch.bool).to(self.device),
            torch.as_tensor(truncated, dtype=torch.bool).to(self.device),
            out,
        )

    def close(self) -> None:
        vector_env = getattr(self, "vector_env", None)
        if vector_env is not None:
            vector_env.close()
        if getattr(self, "_local", None) is not None:
            self._local.close()
            self._local = None

    def __enter__(self) -> GymnasiumVectorEnv:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class GymnasiumGoalEnv(GoalEnvMixin, GymnasiumVectorEnv):
    """``num_envs`` copies of a gymnasium goal env behind the batched contract.

    Arguments as `GymnasiumVectorEnv`. The env must have a ``Dict`` observation space with
    ``achieved_goal`` and ``desired_goal`` and a ``compute_reward(achieved_goal, desired_goal,
    info)``. The goal functions are those of copy 0 with ``"sync"``, and of one extra local
    instance with ``"async"`` (``goal_env``).
    """

    _needs_local_env = True

    @property
    def goal_env(self) -> gym.Env:
        """The unwrapped in-process env whose goal functions are called."""
        return self.first_env

    def _check_env(self, space: gym.spaces.Space, unwrapped: gym.Env | None) -> None:
        keys = list(space.spaces) if isinstance(space, gym.spaces.Dict) else None
        if keys is None or not {"achieved_goal", "desired_goal"} <= set(keys):
            found = f"Dict keys {keys}" if keys is not None else f"{type(space).__name__} space"
            raise ValueError(
                f"env {self.env_id!r} is not a goal env: its observation space must be a Dict with "
                f"'achieved_goal' and 'desired_goal'; found {found}"
            )
        if not callable(getattr(unwrapped, "compute_reward", None)):
            raise ValueError(
                f"env {self.env_id!r} is not a goal env: it has no compute_reward(achieved_goal, desired_goal, info)"
            )

    def _goal_fn(self, fn: Callable, achieved_goal: Any, desired_goal: Any, info: Any) -> np.ndarray:
        """``fn`` on numpy batches; a per-row loop when ``fn`` is not vectorised (scalar result)."""
        a, d = self._to_numpy(achieved_goal), self._to_numpy(desired_goal)
        batch_shape = a.shape[:-1]
        result = np.asarray(fn(a, d, info))
        if result.shape != batch_shape:
            flat_a, flat_d = a.reshape(-1, a.shape[-1]), d.reshape(-1, d.shape[-1])
            rows = [np.asarray(fn(flat_a[i], flat_d[i], info)) for i in range(flat_a.shape[0])]
            result = np.stack(rows).reshape(batch_shape) if rows else np.zeros(batch_shape)
        return result

    def compute_reward(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor, info: Any = None) -> torch.Tensor:
        """The env's own ``compute_reward`` on a batch, as a float32 tensor on ``device``."""
        r = self._goal_fn(self.goal_env.compute_reward, achieved_goal, desired_goal, info)
        return torch.as_tensor(r, dtype=torch.float32).to(self.device)

    def compute_terminated(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor, info: Any = None) -> torch.Tensor:
        """The env's own ``compute_terminated`` (False where it has none), one bool per row."""
        fn = getattr(self.goal_env, "compute_terminated", None)
        if not callable(fn) or _never_terminates(self.goal_env):
            return super().compute_terminated(achieved_goal, desired_goal, info)
        t = self._goal_fn(fn, achieved_goal, desired_goal, info)
        return torch.as_tensor(t.astype(bool)).to(self.device)

    def __enter__(self) -> GymnasiumGoalEnv:
        return self
