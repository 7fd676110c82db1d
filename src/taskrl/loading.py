"""A trained run, read back: its agent (`load`), re-evaluated (`evaluate_run`) with intervals.

Only safetensors and JSON are read: loading never executes code, and never imports a module the run
directory names.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import torch

from taskrl import config as config_io
from taskrl.checkpoint import checkpoint_at, checkpoint_step, read_checkpoint
from taskrl.config import TrainConfig
from taskrl.envs.registry import env_family
from taskrl.errors import ConfigError
from taskrl.plan import validate
from taskrl.runmodes.registry import progress_axis
from taskrl.wiring.calls import import_env_module
from taskrl.wiring.checkpoints import load_agent_state
from taskrl.wiring.parts import (
    EVAL_SEED_OFFSET,
    env_request,
    make_agent,
    make_env,
    make_evaluator,
    resolve_device,
    use_run_threads,
)

__all__ = ["RunSpaces", "evaluate_run", "load", "load_run", "per_task_intervals", "wilson_interval"]


def _saved_config(run_dir: Path, env: Any, env_module: str | None) -> tuple[TrainConfig, Any]:
    """A run directory's config and the env source a caller passed for it."""
    if not (run_dir / "config.json").exists():
        raise ConfigError("run_dir", f"{run_dir} is not a run directory (no config.json)")
    config = config_io.load(run_dir / "config.json")
    if env_module:
        import_env_module(env_module)
    if env is not None and (not isinstance(env, str)):
        return config, env
    return config, None


def held_out_objects(run_dir: str | Path) -> bool:
    """Whether the run's env family declares held-out objects (``--held-out`` then evaluates on them, for any
    algorithm; otherwise it means the held-out tasks of a prompted policy)."""
    config, _ = _saved_config(Path(run_dir), None, None)
    return env_family(config.env).held_out is not None


def load(
    run_dir: str | Path, device: str = "cpu", env: Any = None, env_module: str | None = None, checkpoint: int | None = None
) -> Any:
    """The trained agent of a run directory; ``agent.act(obs)`` takes the environment's observations.

    Only safetensors and JSON are read: loading never executes code, and never imports a module
    the run directory names (pass ``env_module`` to register a gymnasium id of yours first).

    Args:
        run_dir: a directory written by `train`.
        device: where the networks go.
        env: the Python factory or TaskSet the run was trained on, if it was trained on one.
        env_module: a module to import first (one that registers the run's gymnasium id).
        checkpoint: the env step of the checkpoint to load (default the latest); the loaded agent's
            ``loaded_step`` says which.
    """
    return load_run(run_dir, device, env, env_module, checkpoint)[0]


@dataclasses.dataclass(frozen=True)
class RunSpaces:
    """The spaces (and task set) of a run's env, and what it declares about its pictures (``picture_coordinates``,
    ``picture_pose``): what its agent is built from."""

    single_observation_space: gym.spaces.Space
    single_action_space: gym.spaces.Space
    task_set: Any = None
    picture_coordinates: tuple = ()
    picture_pose: Any = None

    def close(self) -> None:
        """Nothing to release."""


def load_run(
    run_dir: str | Path, device: str = "cpu", env: Any = None, env_module: str | None = None, checkpoint: int | None = None
) -> tuple[Any, TrainConfig, RunSpaces]:
    """``(agent, config, spaces)`` of a run directory (arguments as `load`); the env is built
    once, or not at all where its family can give the spaces without it (Meta-World)."""
    run_dir = Path(run_dir)
    config, source = _saved_config(run_dir, env, env_module)
    dev = resolve_device(device)
    family = env_family(config.env)
    request = dataclasses.replace(env_request(config, dev, source, evaluation=True), eval_episodes=1)
    if family.spec is not None and source is None:  # spaces and task set only: building Meta-World takes seconds
        built = family.spec(config.env_settings, request)
    else:
        built = family.make(config.env_settings, request)
    try:
        spaces = RunSpaces(
            built.single_observation_space,
            built.single_action_space,
            getattr(built, "task_set", None),
            tuple(getattr(built, "picture_coordinates", ())),
            getattr(built, "picture_pose", None),
        )
        agent = make_agent(config, built, dev)
    finally:
        built.close()
    folder = checkpoint_at(run_dir / "checkpoints", checkpoint)
    load_agent_state(agent, read_checkpoint(folder, ("agent",), dev)["agent"], folder / "agent.safetensors")
    agent.loaded_step = checkpoint_step(folder)
    return agent, config, spaces


def per_task_intervals(tasks: dict[str, dict[str, Any]]) -> tuple[dict[str, dict[str, Any]], list[float]]:
    """Each task's row with its 95% Wilson interval, and the interval of all their episodes together."""
    rows = {
        name: {**t, "success_ci95": wilson_interval(t["success_rate"] * t["episodes"], t["episodes"])}
        for name, t in tasks.items()
    }
    total = sum(t["episodes"] for t in tasks.values())
    return rows, wilson_interval(sum(t["success_rate"] * t["episodes"] for t in tasks.values()), total)


def wilson_interval(successes: float, n: int, z: float = 1.96) -> list[float]:
    """The 95% Wilson score interval of a success rate (sound at 0 and 1, where a normal one is not)."""
    if n <= 0:
        return [0.0, 1.0]
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return [max(0.0, centre - half), min(1.0, centre + half)]


def set_acting_search(agent: Any, changes: dict[str, Any]) -> None:
    """Make ``agent`` (one that acts by CEM) search with its `CEMConfig` but for ``changes``; `ConfigError` naming
    ``cem.FIELD`` for a field it lacks or a value it refuses."""
    from taskrl.agents.cem import CEMConfig

    if not hasattr(agent, "use_search"):
        raise ConfigError("cem", f"applies to agents that act by CEM (QT-Opt); this one is a {type(agent).__name__}")
    fields = {f.name for f in dataclasses.fields(CEMConfig)}
    for name in changes:
        if name not in fields:
            raise ConfigError("cem", f"unknown setting {name!r}; allowed: {', '.join(sorted(fields))}")
    agent.use_search(dataclasses.replace(agent.cem.config, **changes))


def evaluate_run(
    run_dir: str | Path,
    episodes: int = 100,
    seed: int | None = None,
    device: str = "cpu",
    env: Any = None,
    env_module: str | None = None,
    checkpoint: int | None = None,
    stochastic: bool = False,
    video: int = 0,
    held_out: bool = False,
    cem: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Re-evaluate a saved agent on ``episodes`` fresh episodes (per task on multi-task envs).

    Args:
        run_dir: a run directory.
        episodes: episodes (per task on multi-task envs).
        seed: evaluation seed (default the run's own evaluation seed: the same episodes it was scored on).
        device: where the networks go.
        env: as for `load`.
        env_module: as for `load`.
        checkpoint: the env step of the checkpoint to evaluate (default the latest).
        stochastic: act with the algorithm's exploration instead of greedily.
        video: also record this many episodes to ``run_dir/videos/`` (MP4).
        held_out: evaluate on the env family's held-out objects (a family that declares ``held_out``).
        cem: act with these `CEMConfig` fields changed (an agent that acts by CEM, QT-Opt), e.g. a wider search
            ``{"samples": 256, "iterations": 3, "elites": 24}``; the result's ``cem`` holds the search used.

    Returns:
        ``success_rate`` with its 95% Wilson interval ``success_ci95``, ``eval_return`` with
        ``eval_return_ci95`` (normal, over episodes; single-task envs), ``eval_length``, ``episodes``,
        ``checkpoint_step``, on multi-task envs a ``success/<task>`` per task and ``tasks`` (each with
        its own interval), and ``videos`` (paths) when asked.
    """
    run_dir = Path(run_dir)
    if video:  # MuJoCo renders off-screen through EGL without a display; read when MuJoCo is first imported
        os.environ.setdefault("MUJOCO_GL", "egl")
    config, source = _saved_config(run_dir, env, env_module)
    config = dataclasses.replace(config, evaluation=dataclasses.replace(config.evaluation, eval_episodes=episodes))
    if held_out:
        family = env_family(config.env)
        if family.held_out is None:
            raise ConfigError("held_out", f"{config.env!r} declares no held-out objects to evaluate on")
        config = dataclasses.replace(config, env_settings=family.held_out(config.env_settings))
    use_run_threads(config)
    if video:  # say so before evaluating, not after
        from taskrl.video import check_can_record

        check_can_record(config)
    try:  # before loading anything
        validate(config)
    except ConfigError as error:  # the only setting this call changes is the episode count
        raise ConfigError("episodes" if error.field == "eval_episodes" else error.field, error.message) from None
    agent = load(run_dir, device, env=source, env_module=None, checkpoint=checkpoint)
    if cem:
        set_acting_search(agent, cem)
    seed = config.seed + EVAL_SEED_OFFSET if seed is None else seed
    eval_env = make_env(config, agent.device, seed=seed, evaluation=True, source=source)
    try:
        run, last = make_evaluator(config, eval_env, agent, seed, stochastic=stochastic, details=True)
        result = {**run(), "episodes": episodes, "checkpoint_step": agent.loaded_step}
        if cem:
            result["cem"] = dataclasses.asdict(agent.cem.config)
        result["checkpoint_unit"] = "gradient updates" if progress_axis(config) == "updates" else "env steps"
    finally:
        eval_env.close()
    if last:  # multi-task: an interval for every task and for the mean's share of episodes
        result["tasks"], result["success_ci95"] = per_task_intervals(last["tasks"])
    else:
        result["success_ci95"] = wilson_interval(result.pop("successes"), episodes)
        returns = torch.tensor(result.pop("returns"), dtype=torch.float64)
        half = 1.96 * returns.std().item() / math.sqrt(len(returns)) if len(returns) > 1 else float("nan")
        result["eval_return_ci95"] = [result["eval_return"] - half, result["eval_return"] + half]
    if video:
        from taskrl.video import record_episodes

        result["videos"] = [str(p) for p in record_episodes(agent, config, run_dir / "videos", video, seed, stochastic)]
    return result
