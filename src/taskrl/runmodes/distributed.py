"""``--distributed``: collectors (and Bellman updaters) as Ray actors around this process, the trainer.

Each role's process builds its own env copies and agent from the run's config (on CPU); the trainer keeps one
env copy for spaces and rewards, the replay and the learner.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import torch

from taskrl.agents.registry import ALGORITHMS, algorithm
from taskrl.config import TrainConfig
from taskrl.distributed.limiter import UpdateToDataLimiter
from taskrl.distributed.loop import CALLS_PER_COLLECTOR, DistributedLoop
from taskrl.distributed.pools import LocalPool, Pool
from taskrl.distributed.roles import BellmanUpdater, Collector
from taskrl.distributed.settings import DistributedConfig
from taskrl.envs.base import BatchedEnv
from taskrl.envs.registry import env_family
from taskrl.errors import require
from taskrl.runmodes.spec import RunMode
from taskrl.training.bookkeeping import Bookkeeping
from taskrl.training.offpolicy import batch_sampler
from taskrl.wiring.calls import import_env_module
from taskrl.wiring.parts import RunParts, env_request, make_agent, make_env, use_run_threads

__all__ = ["DISTRIBUTED", "collector_env", "distributed_loop", "local_pool", "ray_pool", "role_agent"]

#: ``(role class, constructor arguments of each, cluster settings) -> pool`` of role objects.
PoolFactory = Callable[[type, list[tuple], DistributedConfig], Pool]


def collector_env(config: TrainConfig, source: Any, num_envs: int, seed: int) -> BatchedEnv:
    """A collector's env copies (built in the collector's process, on CPU)."""
    import_env_module(config.env_module)
    return make_env(config, "cpu", num_envs=num_envs, seed=seed, source=source)


def role_agent(config: TrainConfig, env: Any = None, source: Any = None) -> Any:
    """The run's agent on CPU in a role's process: for ``env`` (a collector's), or for the run's spaces."""
    use_run_threads(config)
    if env is not None:
        return make_agent(config, env, torch.device("cpu"))
    import_env_module(config.env_module)
    family = env_family(config.env)
    request = dataclasses.replace(env_request(config, torch.device("cpu"), source), num_envs=1)
    built = family.make(config.env_settings, request)
    try:
        return make_agent(config, built, torch.device("cpu"))
    finally:
        built.close()


def ray_pool(role: type, args: list[tuple], cluster: DistributedConfig) -> Pool:
    """Each role object a Ray actor (a process of its own, restarted where it dies)."""
    from taskrl.distributed.actors import RayPool

    return RayPool(role, args, num_cpus=cluster.actor_cpus, max_restarts=cluster.max_restarts)


def local_pool(role: type, args: list[tuple], cluster: DistributedConfig) -> Pool:
    """Each role object in this process, each call run as it is submitted (tests, debugging: no Ray)."""
    return LocalPool([role(*a) for a in args])


def distributed_loop(parts: RunParts, books: Bookkeeping, pool: PoolFactory = ray_pool) -> DistributedLoop:
    """Collectors (and Bellman updaters) around this process, the trainer; each role pool built by ``pool``."""
    c, cluster = parts.config, parts.config.cluster
    each = cluster.envs_each(c.num_envs)
    at = books.state.env_steps  # a resumed run's collectors start from new seeds
    collector_args = [
        (
            functools.partial(collector_env, c, parts.source, each),
            functools.partial(role_agent, c),
            c.seed + 10_007 * (i + 1) + at,
            c.threads,
        )
        for i in range(cluster.collectors)
    ]
    collectors = pool(Collector, collector_args, cluster)
    parts.on_close.append(collectors.close)
    updaters = None
    if cluster.bellman_updaters:
        updater_args = [
            (functools.partial(role_agent, c, None, parts.source), c.seed + 20_011 * (j + 1) + at, c.threads)
            for j in range(cluster.bellman_updaters)
        ]
        updaters = pool(BellmanUpdater, updater_args, cluster)
        parts.on_close.append(updaters.close)
    limiter = UpdateToDataLimiter(
        c.updates_per_step,
        c.learning_starts,
        c.data.offline_updates,
        lead_steps=CALLS_PER_COLLECTOR * cluster.collectors * each * cluster.collector_steps,
        enabled=cluster.limit_updates,
    )
    sample_batch = batch_sampler(parts.sampler, c.batch_size, parts.generator)
    return DistributedLoop(
        parts.agent, parts.replay, sample_batch, collectors, updaters, cluster, c.total_steps, limiter, each, books
    )


def steps_in_flight(config: TrainConfig, env: BatchedEnv) -> int:
    """``total_steps`` and the collect calls that may be in flight when it is reached."""
    cluster = config.cluster
    return (
        config.total_steps
        + cluster.collectors * cluster.envs_each(config.num_envs) * CALLS_PER_COLLECTOR * cluster.collector_steps
    )


def start_cluster(parts: RunParts) -> None:
    """Reach (or start) Ray before anything is written: an unreachable cluster is one line."""
    from taskrl.distributed.actors import start_ray

    cluster = parts.config.cluster
    if start_ray(cluster, cluster.collectors + cluster.bellman_updaters):
        import ray

        parts.on_close.append(ray.shutdown)


def fits_a_cluster(config: TrainConfig) -> None:
    """What acts in the one-process loop only, and Bellman updaters only for algorithms that split their update."""
    require(
        config.data.scripted_exploration == 0,
        "scripted_exploration",
        "acts in the one-process loop only (not with --distributed): use --scripted-exploration 0 there",
    )
    if config.cluster.bellman_updaters > 0:
        splitting = [a.name for a in ALGORITHMS.values() if a.bellman_updaters]
        require(
            algorithm(config.algo).bellman_updaters,
            "bellman_updaters",
            f"{config.algo} computes its targets in the trainer (the Ape-X layout): use 0; updaters serve {', '.join(splitting)}",
        )


DISTRIBUTED = RunMode(
    name="distributed",
    summary="--distributed: collectors and Bellman updaters as Ray actors around the trainer",
    applies=lambda config: config.cluster.distributed,
    selected_by="distributed",
    make_loop=distributed_loop,
    loops=("off_policy",),
    trainer_env="one",
    own_steps=steps_in_flight,
    prepare=start_cluster,
    check=fits_a_cluster,
)
