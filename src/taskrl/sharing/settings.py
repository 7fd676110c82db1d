"""The ``data_sharing`` section of a run's configuration: which strategy shares data between tasks, and its settings."""

from __future__ import annotations

import dataclasses
from typing import Any

from taskrl.errors import require
from taskrl.sharing.registry import sharing_strategy

__all__ = ["SharingConfig"]


@dataclasses.dataclass
class SharingConfig:
    """How a multi-task run with known task rewards shares data between tasks (``docs/sharing.md``).

    Attributes:
        sharing: where each task's rows come from, besides its own data: ``none`` (own data only), or a registered
            strategy (``taskrl train --help`` lists them, with what each shares; a strategy registered with
            [`register_sharing_strategy`][taskrl.sharing.registry.register_sharing_strategy] is one more choice).
            Needs an env whose tasks are reward functions (``gridtasks``, ``pointtasks``, or one with
            ``task_reward``, ``task_terminated`` and ``task_success``).
        share_fraction: the share of each task's rows drawn from other tasks' data (all of them
            for a task with no data of its own; none when the strategy finds no data to share).
        strategy_settings: the chosen strategy's own settings (its ``settings`` class, saved in ``config.json`` under
            its name inside ``data_sharing``: ``{"sharing": "hipi", "hipi": {"hipi_temperature": 1.0}}``); None for
            a strategy without any.
    """

    sharing: str = "none"
    share_fraction: float = 0.5
    strategy_settings: Any = None

    def __post_init__(self) -> None:
        if self.strategy_settings is None:
            own = sharing_strategy(self.sharing).settings
            self.strategy_settings = own() if own is not None else None

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting (the strategy's name is checked
        against the registry by [`taskrl.plan.resolve`][taskrl.plan.resolve])."""
        require(0.0 <= self.share_fraction <= 1.0, "share_fraction", f"must be in [0, 1] (got {self.share_fraction})")
        if self.strategy_settings is not None:
            self.strategy_settings.validate()
