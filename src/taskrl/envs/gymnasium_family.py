"""The ``gym`` family: any gymnasium environment, a user's own included.

``--env-id my/Slider-v0`` (or ``taskrl.train(preset, env="my/Slider-v0")``) trains on a registered
id; ``taskrl.train(preset, env=make_slider)`` on a zero-argument factory of a ``gymnasium.Env``.
Either may be

- a goal env: a ``Dict`` observation with ``observation`` / ``achieved_goal`` / ``desired_goal``
  and a ``compute_reward(achieved_goal, desired_goal, info)`` (hindsight relabelling applies), or
- a plain env: a ``Box`` observation (read as ``observation``), or a ``Dict`` of ``Box`` entries,

with ``Box`` or ``Discrete`` actions. Success is the step info's ``is_success`` (or ``success``)
where the env reports one. ``--env-module mypkg.envs`` imports the module that registers the id.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym

from taskrl.envs.base import BatchedEnv
from taskrl.envs.camera import CameraSettings
from taskrl.envs.gymnasium_adapter import VECTOR_STRATEGIES, GymnasiumGoalEnv, GymnasiumVectorEnv
from taskrl.envs.pixels import check_pixel_settings, pixel_factory
from taskrl.envs.spec import EnvFamily, EnvRequest
from taskrl.errors import ConfigError, one_of, require

__all__ = ["FAMILY", "GymnasiumSettings", "PYTHON_SOURCE", "factory_name"]

#: ``env_id`` of a run trained on a Python object: ``python:<module>.<name>`` (it must be passed again).
PYTHON_SOURCE = "python:"


@dataclasses.dataclass
class GymnasiumSettings(CameraSettings):
    """Settings of the ``gym`` family (any gymnasium environment).

    Attributes:
        env_id: the gymnasium id, e.g. ``my/Slider-v0``; given alone it selects this family. A run
            trained on a Python factory records it as ``python:<module>.<name>``.
        max_episode_steps: episode length; 0 = the id's registered time limit.
        success_key: step-info key of success; ``auto`` reads ``is_success`` or ``success`` where the
            env reports one (else no episode counts as a success; the return still measures learning).
        vector_strategy: ``sync`` (one process) or ``async`` (one process per copy).
        observation: ``state`` (the env's own observation), ``pixels`` (its rendered frame as ``image``; a goal
            env keeps its goals as vectors) or ``pixels+state``; a factory of yours is then called with
            ``render_mode="rgb_array"`` (and ``width`` / ``height`` where it takes them). See ``envs/pixels.py``.
        image_size: the side of the rendered picture in pixels (``pixels`` modes).
    """

    env_id: str = ""
    max_episode_steps: int = 0
    success_key: str = "auto"
    vector_strategy: Literal["sync", "async"] = "sync"
    observation: Literal["state", "pixels", "pixels+state"] = "state"
    image_size: int = 64

    def validate(self) -> None:
        require(
            bool(self.env_id),
            "env_id",
            "name a gymnasium id, e.g. --env-id my/Slider-v0 (with --env-module MODULE if a module of yours registers it)",
        )
        require(
            self.max_episode_steps >= 0,
            "max_episode_steps",
            f"must be >= 0 (0 = the registered limit; got {self.max_episode_steps})",
        )
        one_of(self.vector_strategy, VECTOR_STRATEGIES, "vector_strategy", "strategy")
        super().validate()
        check_pixel_settings(self)


def factory_name(obj: Any) -> str:
    """``python:<module>.<qualname>`` of a Python object a run was built from (for the record)."""
    return f"{PYTHON_SOURCE}{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', type(obj).__name__)}"


def check_registered(env_id: str) -> None:
    """A `ConfigError` on ``env_id`` unless gymnasium knows the id."""
    try:
        gym.spec(env_id)
    except gym.error.Error as error:
        raise ConfigError(
            "env_id",
            f"{env_id!r} is not registered with gymnasium ({error}); register it first, "
            f"e.g. with --env-module MODULE naming the module that calls gymnasium.register",
        ) from None


def _factory(settings: GymnasiumSettings, source: Any):
    """A zero-argument factory of one copy: the Python factory given, or ``gymnasium.make`` of the id."""
    if source is not None:
        return source
    if settings.env_id.startswith(PYTHON_SOURCE):
        raise ConfigError(
            "env",
            f"this run was trained on the Python factory {settings.env_id[len(PYTHON_SOURCE) :]}; "
            f"pass it again (taskrl.train(resume=..., env=factory) or taskrl.load(..., env=factory))",
        )
    check_registered(settings.env_id)
    return None


def _make(settings: GymnasiumSettings, request: EnvRequest) -> BatchedEnv:
    factory = _factory(settings, request.source)
    if settings.observation != "state":
        factory = pixel_factory(factory if factory is not None else settings.env_id, settings.observation, settings.image_size)
    source = factory if factory is not None else settings.env_id
    probe = factory() if factory is not None else gym.make(settings.env_id)
    try:  # one copy tells whether this is a goal env (then hindsight relabelling uses its compute_reward)
        space = probe.observation_space
        goal = (
            isinstance(space, gym.spaces.Dict)
            and {"achieved_goal", "desired_goal"} <= set(space.spaces)
            and callable(getattr(probe.unwrapped, "compute_reward", None))
        )
    finally:
        probe.close()
    cls = GymnasiumGoalEnv if goal else GymnasiumVectorEnv
    try:
        return cls(
            source,
            num_envs=request.copies,
            device=request.device,
            vector_strategy=settings.vector_strategy,
            success_key=settings.success_key,
            max_episode_steps=settings.max_episode_steps or None,
        )
    except ValueError as error:  # the adapter's one-line reason (observation space, time limit)
        raise ConfigError("env_id", str(error)) from None


def _persist(source: Any, run_dir: Path) -> dict[str, Any]:
    return {"env_id": factory_name(source)}


FAMILY = EnvFamily(
    name="gym",
    description="any gymnasium environment (--env-id ID): goal envs (Dict with achieved/desired goal) or Box observations",
    section="gym",
    settings=GymnasiumSettings,
    make=_make,
    selected_by="env_id",
    accepts=callable,
    persist=_persist,
    video_env=lambda s: (
        None
        if s.env_id.startswith(PYTHON_SOURCE)
        else gym.make(
            s.env_id, render_mode="rgb_array", **({"max_episode_steps": s.max_episode_steps} if s.max_episode_steps else {})
        )
    ),
)
