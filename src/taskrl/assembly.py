"""All parts of a run from its config, for the run mode it runs in: envs, agent, replay, relabeller, sampler."""

from __future__ import annotations

from typing import Any

import torch

from taskrl.envs.base import BatchedEnv
from taskrl.errors import require
from taskrl.plan import RunPlan
from taskrl.replay import EpisodeReplay, RecentMixSampler, TaskBalancedSampler
from taskrl.replay.pipeline import Draw, SamplerPipeline, Stage, UniformDraw, hindsight_stage
from taskrl.sharing import TaskSharing
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


def build_parts(plan: RunPlan, source: Any = None) -> RunParts:
    """Envs, agent, replay, relabeller and sampler of a resolved run, as its mode needs them (``source``: a
    Python object the env family builds its envs from, e.g. a factory or a TaskSet)."""
    config, mode, family = plan.config, plan.mode, plan.family
    if config.threads:
        torch.set_num_threads(config.threads)
    device = resolve_device(config.device)
    torch.manual_seed(config.seed)
    if mode.trainer_env == "spaces" and family.spec is not None and source is None:
        env = family.spec(config.env_settings, env_request(config, device))
    elif mode.trainer_env == "one":
        env = make_env(config, device, num_envs=1, source=source, family=family)
    else:
        env = make_env(config, device, source=source, family=family)
    eval_env = None
    try:
        eval_env = make_env(config, device, evaluation=True, source=source, family=family)
        agent = make_agent(config, env, device, plan.algorithm)
        if config.compile not in ("off", "auto"):  # auto is settled before building (`resolve_compile`)
            agent.compile(config.compile)
        generator = torch.Generator(device=device)
        generator.manual_seed(config.seed + 1)
        parts = RunParts(config, family, device, env, eval_env, agent, generator, source=source)
        if plan.algorithm.loop == "off_policy":
            _add_replay(parts, plan, replay_needs(config, env, mode.own_steps))
        if mode.prepare is not None:
            mode.prepare(parts)
        return parts
    except BaseException:
        env.close()
        if eval_env is not None:
            eval_env.close()
        raise


def _add_replay(parts: RunParts, plan: RunPlan, needs: int) -> None:
    """The replay (``buffer_size`` transitions, or fewer where the run can store no more), its relabeller and
    the sampler the sampling settings ask for."""
    config, env, device = parts.config, parts.env, parts.device
    capacity = min(config.replay.buffer_size, needs)
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
    parts.sampler = sampler_pipeline(plan, env, parts)


def sampler_pipeline(plan: RunPlan, env: BatchedEnv, parts: RunParts) -> SamplerPipeline:
    """The run's batches: a draw (uniform, task-balanced, or a sharing strategy's), optionally mixed with a
    window of recent episodes, then the stages (the sharing strategy's task relabel, hindsight relabelling)."""
    config, replay = plan.config, parts.replay
    draw: Draw = UniformDraw(replay)
    stages: list[Stage] = []
    if config.replay.sampling == "task_balanced":
        parts.sharing = _task_sharing(plan, env, parts.agent, replay)
        if parts.sharing is not None:
            draw = parts.sharing
            stages.append(parts.sharing.to_task)
        else:
            draw = TaskBalancedSampler(replay, len(env.task_set))
    if config.replay.recent_fraction > 0:
        draw = RecentMixSampler(replay, config.replay.recent_fraction, config.replay.recent_episodes, draw)
    if parts.relabel is not None:
        stages.append(hindsight_stage(parts.relabel, replay))
    return SamplerPipeline(replay, draw, stages)


def _task_sharing(plan: RunPlan, env: BatchedEnv, agent: Any, replay: EpisodeReplay) -> TaskSharing | None:
    """Task-balanced batches with the run's sharing strategy, on an env that scores any task; None
    (plain task-balanced sampling) on one that cannot. What a strategy needs was checked by ``validate``
    from the family's and the algorithm's declarations; the built env is held to its family's."""
    config, chosen = plan.config, plan.sharing
    if not task_functions(env):
        require(
            not chosen.shares,
            "sharing",
            f"needs an env whose tasks are reward functions (task_reward, task_terminated, task_success); "
            f"the env {config.env!r} built has none",
        )
        return None
    q_value = agent.q_value if plan.algorithm.q_values else None
    return TaskSharing(replay, env, len(env.task_set), config.data_sharing, q_value, strategy=chosen)
