"""The run's own sections of ``config.json``: the replay, evaluation, checkpoints, and where the data comes from.

Each section validates its own settings; the command line still takes each setting by its short name
(``--eval-interval``) or in its section (``--evaluation.eval-interval``).
"""

from __future__ import annotations

import dataclasses
from typing import Literal

from taskrl.errors import one_of, require

__all__ = [
    "HER_STRATEGIES",
    "RUN_SECTIONS",
    "SAMPLINGS",
    "CheckpointSettings",
    "DataSettings",
    "EvaluationSettings",
    "ReplaySettings",
]

SAMPLINGS = ("uniform", "task_balanced")
HER_STRATEGIES = ("future", "final", "episode", "random", "none")


def _at_least(section: object, low: float, *names: str) -> None:
    for name in names:
        value = getattr(section, name)
        require(value >= low, name, f"must be >= {low} (got {value})")


def _fraction(section: object, *names: str) -> None:
    for name in names:
        value = getattr(section, name)
        require(0.0 <= value <= 1.0, name, f"must be in [0, 1] (got {value})")


@dataclasses.dataclass
class ReplaySettings:
    """What the replay keeps and how batches are drawn from it (off-policy runs).

    Attributes:
        buffer_size: replay capacity in transitions.
        her: hindsight strategy (``none`` disables relabelling).
        her_k: relabelled transitions per real one; the relabelled fraction is k/(k+1).
        sampling: ``uniform`` over stored transitions, or ``task_balanced`` (multi-task envs: the
            same number of transitions of every task in each batch).
        recent_fraction: share of each batch drawn from the most recent ``recent_episodes`` episodes
            (QT-Opt's on-policy buffer beside its store of all data); 0 = uniform over everything stored.
        recent_episodes: the size of that window, in episodes.
    """

    buffer_size: int = 1_000_000
    her: Literal["future", "final", "episode", "random", "none"] = "future"
    her_k: int = 4
    sampling: Literal["uniform", "task_balanced"] = "uniform"
    recent_fraction: float = 0.0
    recent_episodes: int = 1_000

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting."""
        one_of(self.her, HER_STRATEGIES, "her", "strategy")
        one_of(self.sampling, SAMPLINGS, "sampling", "sampling")
        _at_least(self, 1, "buffer_size", "recent_episodes")
        _at_least(self, 0, "her_k")
        _fraction(self, "recent_fraction")


@dataclasses.dataclass
class EvaluationSettings:
    """When and how the greedy policy is scored.

    Attributes:
        eval_interval: environment steps between evaluations.
        eval_episodes: episodes per evaluation (greedy policy, fixed evaluation seeds); on
            multi-task envs, episodes per task (Meta-World: over distinct goal positions, at most 50).
        stop_at_success: stop once evaluation success reaches this (0 = train to total_steps).
    """

    eval_interval: int = 5_000
    eval_episodes: int = 100
    stop_at_success: float = 0.0

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting."""
        _at_least(self, 1, "eval_interval", "eval_episodes")
        _fraction(self, "stop_at_success")


@dataclasses.dataclass
class CheckpointSettings:
    """When the run is saved, and what with.

    Attributes:
        checkpoint_interval: environment steps between checkpoints (also one after the first step
            and one at the end).
        checkpoint_minutes: also checkpoint after this many minutes of wall-clock since the last
            checkpoint, so a killed run loses at most that much (0 = by env steps only).
        save_replay: include the replay buffer in checkpoints so a resumed run loses no data. An ``--offline`` run
            leaves it out (its replay is the stored data, unchanged) and reads the data again when resumed.
        init_from: a run directory whose last checkpoint's agent (networks, targets, optimiser, input
            statistics) this new run starts from instead of a fresh one: QT-Opt's online phase after an
            ``--offline`` run, or fine-tuning. Same algorithm, env and network sizes as that run; its replay is
            not taken (``--offline-data`` does that). Counters start at 0.
    """

    checkpoint_interval: int = 50_000
    checkpoint_minutes: float = 10.0
    save_replay: bool = True
    init_from: str = ""

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting."""
        _at_least(self, 1, "checkpoint_interval")
        require(
            self.checkpoint_minutes >= 0,
            "checkpoint_minutes",
            f"must be >= 0 (0 = by env steps only; got {self.checkpoint_minutes})",
        )


@dataclasses.dataclass
class DataSettings:
    """Where the training data comes from besides the agent's own acting: stored data, scripted episodes.

    Attributes:
        offline: learn from stored data only, never stepping an env to collect (the env's
            ``--dataset-quality`` datasets, or ``--offline-data``); ``total_steps``, ``eval_interval`` and
            ``checkpoint_interval`` then count gradient updates; evaluation still runs in the env.
        offline_data: a run directory whose last checkpoint's replay preloads this run's replay
            (QT-Opt's offline data, then online); its env must have the same spaces.
        offline_updates: gradient updates on the preloaded data before collection starts.
        scripted_exploration: share of training episodes acted by the env's scripted policy instead of the
            agent (QT-Opt's first data came from a scripted grasp that succeeded 15-30% of the time); envs with
            one have a ``scripted_action(obs)`` method (``grasp``). 0 = the agent acts in every episode.
        scripted_steps: env steps during which ``scripted_exploration`` applies (0: the whole run).
    """

    offline: bool = False
    offline_data: str = ""
    offline_updates: int = 0
    scripted_exploration: float = 0.0
    scripted_steps: int = 0

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting."""
        _at_least(self, 0, "offline_updates")
        _fraction(self, "scripted_exploration")
        require(
            self.scripted_steps >= 0,
            "scripted_steps",
            f"must be >= 0 env steps (0: the whole run; got {self.scripted_steps})",
        )
        require(
            self.offline_updates == 0 or bool(self.offline_data),
            "offline_updates",
            "updates before collection need data to learn from: --offline-data RUN_DIR",
        )


#: the run's own sections of ``config.json``, by name (their settings keep their short names on the command line, as
#: run-level ones do)
RUN_SECTIONS: dict[str, type] = {
    "replay": ReplaySettings,
    "evaluation": EvaluationSettings,
    "checkpoints": CheckpointSettings,
    "data": DataSettings,
}
