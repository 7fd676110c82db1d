"""All parts of a run from its config, for the run mode it runs in: envs, agent, replay, relabeller, sampler."""

from __future__ import annotations

from typing import Any

import torch

from taskrl.agents.registry import algorithm
from taskrl.config import TrainConfig
from taskrl.envs.base import BatchedEnv
from taskrl.envs.registry import env_family
from taskrl.errors import require
from taskrl.replay import EpisodeReplay, RecentMixSampler, TaskBalancedSampler
from taskrl.runmodes.spec import RunMode
from taskrl.sharing import TaskSharing
from taskrl.sharing.registry import sharing_strategy
from taskrl.sharing.strategies import task_functions
from taskrl.wiring.parts import (
    RunParts,
    check_replay_memory,
    env_request,
    make_agent,
    make_env,
    make_relabeler,
    resolve_device,
)
from taskrl.wiring.stored_data import replay_needs

__all__ = ["build_parts"]


def build_parts(config: TrainConfig, mode: RunMode, source: Any = None) -> RunParts:
    """Envs, agent, replay, relabeller and sampler of a validated config, as ``mode`` needs them (``source``: a
    Python object the env family builds its envs from, e.g. a factory or a TaskSet)."""
    if config.threads:
        torch.set_num_threads(config.threads)
    device = resolve_device(config.device)
    torch.manual_seed(config.seed)
    family = env_family(config.env)
    if mode.trainer_env == "spaces" and family.spec is not None and source is None:
        env = family.spec(config.env_settings, env_request(config, device))
    elif mode.trainer_env == "one":
        env = make_env(config, device, num_envs=1, source=source)
    else:
        env = make_env(config, device, source=source)
    eval_env = None
    try:
        eval_env = make_env(config, device, evaluation=True, source=source)
        agent = make_agent(config, env, device)
        if config.compile != "off":
            agent.compile(config.compile)
        generator = torch.Generator(device=device)
        generator.manual_seed(config.seed + 1)
        parts = RunParts(config, family, device, env, eval_env, agent, generator, source=source)
        if algorithm(config.algo).loop == "off_policy":
            _add_replay(parts, replay_needs(config, env, mode.own_steps))
        if mode.prepare is not None:
            mode.prepare(parts)
        return parts
    except BaseException:
        env.close()
        if eval_env is not None:
            eval_env.close()
        raise


def _add_replay(parts: RunParts, needs: int) -> None:
    """The replay (``buffer_size`` transitions, or fewer where the run can store no more), its relabeller and
    the sampler the sampling settings ask for."""
    config, env, device = parts.config, parts.env, parts.device
    capacity = min(config.buffer_size, needs)
    horizon = getattr(env, "horizon", None)
    check_replay_memory(
        EpisodeReplay.bytes_needed(
            env.single_observation_space, env.single_action_space, capacity, num_envs=env.num_envs, horizon=horizon
        ),
        capacity,
        device,
    )
    parts.replay = EpisodeReplay(
        env.single_observation_space, env.single_action_space, capacity, num_envs=env.num_envs, device=device, horizon=horizon
    )
    parts.relabel = make_relabeler(config, env)
    if config.sampling == "task_balanced":
        # a recent window mixes with plain task-balanced draws (validate() refuses it beside a strategy)
        sharing = _task_sharing(config, env, parts.agent, parts.replay) if config.recent_fraction == 0 else None
        parts.sampler = parts.sharing = sharing
        if parts.sampler is None:
            parts.sampler = TaskBalancedSampler(parts.replay, len(env.task_set))
    if config.recent_fraction > 0:
        balanced = parts.sampler.indices if parts.sampler is not None else None
        parts.sampler = RecentMixSampler(parts.replay, config.recent_fraction, config.recent_episodes, balanced)


def _task_sharing(config: TrainConfig, env: BatchedEnv, agent: Any, replay: EpisodeReplay) -> TaskSharing | None:
    """Task-balanced batches with the run's sharing strategy, on an env that scores any task; None
    (plain task-balanced sampling) on one that cannot. What a strategy needs was checked by ``validate``
    from the family's and the algorithm's declarations; the built env is held to its family's."""
    chosen = sharing_strategy(config.data_sharing.sharing)
    if not task_functions(env):
        require(
            not chosen.shares,
            "sharing",
            f"needs an env whose tasks are reward functions (task_reward, task_terminated, task_success); "
            f"the env {config.env!r} built has none",
        )
        return None
    q_value = agent.q_value if algorithm(config.algo).q_values else None
    return TaskSharing(replay, env, len(env.task_set), config.data_sharing, q_value, strategy=chosen)
