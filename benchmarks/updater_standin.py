"""Bellman updaters standing in for machines of their own: each label takes a fixed wall time (sleep)
instead of CPU, so the trainer -> queue -> updaters -> trainer pipeline can be scaled past this
machine's 2 cores. The trainer side is taskrl's own DistributedLoop, fed from a preloaded replay."""

from __future__ import annotations

import functools
import time
from pathlib import Path

import torch

from taskrl.distributed.actors import RayPool, start_ray
from taskrl.distributed.limiter import UpdateToDataLimiter
from taskrl.distributed.loop import IDLE_WAIT, DistributedLoop
from taskrl.distributed.pools import LocalPool
from taskrl.distributed.roles import BellmanUpdater, Labelled, pull_weights
from taskrl.overrides import with_overrides
from taskrl.presets import preset_config
from taskrl.run import build
from taskrl.runmodes.distributed import role_agent
from taskrl.training.bookkeeping import Bookkeeping, LoopState
from taskrl.training.offpolicy import batch_sampler
from taskrl.wiring.stored_data import preload_replay


class SleepyUpdater(BellmanUpdater):
    """A Bellman updater whose targets take ``seconds`` of wall time and no CPU (``y = r``)."""

    def __init__(self, make_agent, seed: int, threads: int, seconds: float) -> None:
        super().__init__(make_agent, seed, threads)
        self.seconds = seconds

    def label(self, batch, version, fetch) -> Labelled:
        started = time.perf_counter()
        pull_weights(self, version, fetch)
        time.sleep(self.seconds)
        return Labelled(batch, batch.reward.clone(), time.perf_counter() - started, self.version)


def measure_updaters(source: Path, count: int, label_seconds: float, seconds: float, per_call: int = 1) -> dict:
    """Targets/s and trainer updates/s of ``count`` stand-in updaters over ``seconds`` (after the first label)."""
    import ray

    config = with_overrides(
        preset_config("pointreach-qtopt-her"),
        {
            "bellman_updaters": count,
            "queue_size": 2 * count * per_call,
            "batches_per_call": per_call,
            "threads": 1,
            "learning_starts": 0,
        },
    )
    parts = build(config)
    preload_replay(parts, source)
    started_ray = start_ray(config.cluster, count)
    pool = RayPool(
        SleepyUpdater,
        [(functools.partial(role_agent, config), 100 + j, 1, label_seconds) for j in range(count)],
        num_cpus=1,
        max_restarts=0,
    )
    books = Bookkeeping(
        LoopState(), lambda: {"success_rate": 0.0}, lambda row: None, lambda s: None, 10**12, 10**12, 10**12, 0.0, parts.device
    )
    limiter = UpdateToDataLimiter(config.updates_per_step, 0, offline_updates=10**12)  # learn only: the offline phase
    sample = batch_sampler(parts.sampler, config.batch_size, parts.generator)
    loop = DistributedLoop(
        parts.agent, parts.replay, sample, LocalPool([]), pool, config.cluster, config.total_steps, limiter, 1, books
    )
    try:
        loop.publish()
        loop.refill()
        while not loop.labelled:  # actors start
            loop.take_labels(1.0)
        loop.meters.reset()
        updates0, t0 = books.state.updates, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            if loop.learn(books.state) == 0:
                loop.take_labels(IDLE_WAIT)
        elapsed = time.perf_counter() - t0
        meters = loop.meters
        return {
            "updaters": count,
            "batches_per_call": per_call,
            "seconds": elapsed,
            "targets_per_s": sum(meters.targets) / elapsed,
            "updates_per_s": (books.state.updates - updates0) / elapsed,
            "queue_depth": meters.queue_depth / max(meters.queue_samples, 1),
            "batch_size": config.batch_size,
            "torch_threads": torch.get_num_threads(),
        }
    finally:
        pool.close()
        parts.close()
        if started_ray:
            ray.shutdown()
