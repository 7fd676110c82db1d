"""Runs that step no env while they train: an offline algorithm on its dataset, and an off-policy algorithm on
stored data only (``--offline``: datasets, another run's replay). Both count progress in gradient updates."""

from __future__ import annotations

from pathlib import Path

from taskrl.agents.registry import algorithm
from taskrl.config import TrainConfig
from taskrl.errors import ConfigError, require
from taskrl.runmodes.spec import RunMode
from taskrl.training.bookkeeping import Bookkeeping
from taskrl.training.offline import OfflineLoop
from taskrl.training.offpolicy import batch_sampler
from taskrl.wiring.parts import RunParts

__all__ = ["DATASET", "STORED_DATA"]


def use_dataset(parts: RunParts) -> None:
    """An offline run's batches: its dataset (``dataset`` of the algorithm's settings), restricted to the
    env's tasks in the env's order, handed to the agent (which returns its sampler)."""
    from taskrl.demos.dataset import read_demonstrations

    config = parts.config
    path = getattr(config.algo_settings, "dataset", "")
    if not path:
        raise ConfigError(
            "dataset", "an offline algorithm learns from a dataset: --dataset DIR (make one with: taskrl demos collect)"
        )
    if not Path(path).exists():
        raise ConfigError("dataset", f"{path} does not exist; make it with: taskrl demos collect {config.env} --out {path}")
    demos = read_demonstrations(path, parts.device).as_seen_under(config.env_settings)
    task_set = getattr(parts.env, "task_set", None)
    if task_set is not None:
        demos = demos.select_tasks(task_set.names)
    parts.sampler = parts.agent.use_dataset(demos)


def dataset_loop(parts: RunParts, books: Bookkeeping) -> OfflineLoop:
    return OfflineLoop(
        parts.agent, parts.sampler.sample, parts.config.total_steps, parts.config.batch_size, books, parts.generator
    )


def stored_data_loop(parts: RunParts, books: Bookkeeping) -> OfflineLoop:
    """An off-policy agent's updates on what the replay holds, relabelled and sampled as online."""
    c = parts.config
    sample_batch = batch_sampler(parts.sampler, c.batch_size, parts.generator)
    return OfflineLoop(parts.agent, lambda size, generator: sample_batch(), c.total_steps, c.batch_size, books, parts.generator)


DATASET = RunMode(
    name="dataset",
    summary="an offline algorithm (imitation) on its dataset; no env is stepped",
    applies=lambda config: algorithm(config.algo).loop == "offline",
    make_loop=dataset_loop,
    loops=("offline",),
    axis="updates",
    trainer_env="spaces",
    prepare=use_dataset,
    evaluate_first=False,
)


def needs_stored_data(config: TrainConfig) -> None:
    """An ``--offline`` run learns from data only: another run's replay or the env's datasets."""
    datasets = bool(getattr(config.env_settings, "dataset_quality", ""))
    require(
        bool(config.data.offline_data) or datasets,
        "offline",
        "learning from stored data only needs data: --offline-data RUN_DIR, or --dataset-quality TASK=QUALITY,...",
    )


STORED_DATA = RunMode(
    name="stored_data",
    summary="--offline: an off-policy algorithm on stored data only (datasets, another run's replay)",
    applies=lambda config: config.data.offline,
    selected_by="offline",
    make_loop=stored_data_loop,
    loops=("off_policy",),
    axis="updates",
    own_steps=lambda config, env: 0,
    check=needs_stored_data,
)
