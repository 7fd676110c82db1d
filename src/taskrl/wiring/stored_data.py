"""Stored data in a run's replay: the env family's datasets (``--dataset-quality``), another run's replay
(``--offline-data``), and how many transitions the replay must hold for both and the run's own steps."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

from taskrl import config as config_io
from taskrl.checkpoint import load_checkpoint
from taskrl.config import TrainConfig
from taskrl.envs.base import BatchedEnv
from taskrl.envs.registry import ENV_FAMILIES
from taskrl.envs.reward_tasks import parse_qualities
from taskrl.errors import ConfigError, reason, require
from taskrl.replay import EpisodeReplay
from taskrl.replay.storage import saved_episodes
from taskrl.sharing import collect_task_datasets
from taskrl.wiring.parts import RunParts, env_request

__all__ = ["check_preload_fits", "dataset_steps", "preload_datasets", "preload_replay", "replay_needs"]

DATASET_SEED_OFFSET = 2_000_003


def _dataset_copies(steps: int) -> int:
    """Env copies per task that make a dataset of ``steps`` transitions (each copy ~40 steps or more)."""
    return max(1, min(50, steps // 40))


def dataset_steps(config: TrainConfig, env: Any) -> int:
    """Transitions of the env's offline datasets (``--dataset-quality``): 0 without any. Each task's
    ``dataset_steps`` is rounded up to a multiple of its env copies (all copies step together)."""
    settings = config.env_settings
    if not getattr(settings, "dataset_quality", ""):
        return 0
    copies = _dataset_copies(settings.dataset_steps)
    return len(env.task_set) * -(-settings.dataset_steps // copies) * copies


def _dataset_families() -> list[str]:
    """The families whose settings name datasets (``dataset_quality``)."""
    return [f.name for f in ENV_FAMILIES.values() if "dataset_quality" in {x.name for x in dataclasses.fields(f.settings)}]


def check_preload_fits(replay: EpisodeReplay, transitions: int, what: str) -> None:
    """A `ConfigError` on ``buffer_size`` when ``transitions`` more would evict stored data: a
    preload is never cut silently."""
    needed = replay.num_transitions + transitions
    require(
        needed <= replay.capacity,
        "buffer_size",
        f"{what} holds {transitions:,} transitions; the replay holds {replay.capacity:,}: use --buffer-size {needed:,} or more",
    )


def preload_datasets(parts: RunParts) -> int:
    """Store the env family's per-task datasets of the qualities ``--dataset-quality`` names; transitions stored."""
    config, env = parts.config, parts.env
    settings = config.env_settings
    qualities = parse_qualities(settings.dataset_quality, env.task_set.names)
    seed = config.seed + DATASET_SEED_OFFSET  # the datasets' own stream, never the training env's
    request = env_request(config, parts.device, parts.source, evaluation=True, seed=seed)
    # the family's evaluation env: fixed tasks per copy, _dataset_copies of each
    maker = parts.family.make(settings, dataclasses.replace(request, eval_episodes=_dataset_copies(settings.dataset_steps)))
    try:
        require(
            callable(getattr(maker, "expert_action", None)) and getattr(maker, "slot_tasks", None) is not None,
            "dataset_quality",
            f"{config.env!r} has no scripted expert to make datasets with; allowed envs: {', '.join(_dataset_families())}",
        )
        check_preload_fits(parts.replay, dataset_steps(config, env), "--dataset-quality's datasets")
        episodes = collect_task_datasets(maker, qualities, settings.dataset_steps, seed)
    finally:
        maker.close()
    check_preload_fits(parts.replay, episodes.num_transitions, "--dataset-quality's datasets")
    parts.replay.add_episodes(episodes)
    return episodes.num_transitions


def replay_needs(config: TrainConfig, env: BatchedEnv, own_steps: Callable[[TrainConfig, BatchedEnv], int]) -> int:
    """Transitions a run can store: its datasets and ``own_steps`` (what the run mode collects itself, the last
    step of every copy past ``total_steps`` included); with ``--offline-data``, everything up to ``buffer_size``
    (the other run's data too). The episodes running at the end are stored cut (their steps are counted)."""
    if config.data.offline_data:
        return config.replay.buffer_size
    return max(dataset_steps(config, env) + own_steps(config, env), 1)


def _where_its_data_is(run_dir: str | Path) -> str:
    """What to do about a run whose checkpoints hold no replay: an --offline run's data are where it read them."""
    try:
        source = config_io.load(Path(run_dir) / "config.json").data
    except (OSError, ValueError):
        source = None
    if source is not None and source.offline and source.offline_data:
        return f"it learnt offline from {source.offline_data}: use --offline-data {source.offline_data}"
    return "train it with --save-replay"


def preload_replay(parts: RunParts, run_dir: str | Path) -> int:
    """Fill the replay with the stored episodes of another run's last checkpoint (``--offline-data``);
    how many episodes it now holds."""
    folder = Path(run_dir) / "checkpoints"
    try:
        saved = load_checkpoint(folder, ("replay",), parts.device)
    except (OSError, KeyError, ValueError, RuntimeError) as error:
        raise ConfigError(
            "offline_data",
            f"{run_dir} has no checkpoint with a replay to start from ({reason(error)}); train it with --save-replay",
        ) from None
    if "replay" not in saved:
        raise ConfigError("offline_data", f"the last checkpoint of {run_dir} holds no replay; {_where_its_data_is(run_dir)}")
    try:
        episodes, _ = saved_episodes(saved["replay"])
    except (KeyError, RuntimeError, ValueError, IndexError) as error:
        raise ConfigError("offline_data", f"the replay of {run_dir} cannot be read: {reason(error)}") from None
    check_preload_fits(parts.replay, episodes.num_transitions, f"--offline-data {run_dir}")
    try:
        parts.replay.add_episodes(episodes.to(parts.device))
    except (KeyError, RuntimeError, ValueError, IndexError) as error:
        raise ConfigError("offline_data", f"the replay of {run_dir} does not fit this run's env: {reason(error)}") from None
    return parts.replay.num_episodes
