"""The ``data_sharing`` section of a run's configuration: which strategy shares data between tasks."""

from __future__ import annotations

import dataclasses

from taskrl.errors import require

__all__ = ["SharingConfig"]


@dataclasses.dataclass
class SharingConfig:
    """How a multi-task run with known task rewards shares data between tasks (``docs/sharing.md``).

    Attributes:
        sharing: where each task's rows come from, besides its own data: ``none`` (own data only),
            ``all`` (any other task's data), ``random`` (the data of ``share_tasks`` other tasks drawn
            anew for every batch), ``success`` (MT-Opt: other tasks' episodes that pass this task's
            success test), ``hipi`` (other tasks' episodes weighted by the inverse-RL posterior of
            this task), ``conservative`` (CDS: other tasks' transitions whose Q-value under this task
            reaches the ``conservative_percentile``-th percentile of its own rows' Q-values) or
            ``zero-reward`` (UDS: any other task's data with reward 0), ``mtopt`` (MT-Opt: other tasks'
            successes and failures under this task, half and half), or a strategy registered with
            [`register_sharing_strategy`][taskrl.sharing.registry.register_sharing_strategy]. Needs an env whose tasks are
            reward functions (``gridtasks``, ``pointtasks``, or one with ``task_reward``,
            ``task_terminated`` and ``task_success``).
        share_fraction: the share of each task's rows drawn from other tasks' data (all of them
            for a task with no data of its own; none when the strategy finds no data to share).
        share_tasks: ``random``: how many other tasks each task draws from.
        hipi_temperature: ``hipi``: the temperature of the posterior ``exp(R_j / T - log Z_j)``.
        conservative_percentile: ``conservative``: the percentile of the task's own rows' Q-values a
            shared row must reach (rows that do not are replaced by the task's own data).
    """

    sharing: str = "none"
    share_fraction: float = 0.5
    share_tasks: int = 1
    hipi_temperature: float = 1.0
    conservative_percentile: float = 50.0

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting (the strategy's name is checked
        against the registry by [`taskrl.plan.resolve`][taskrl.plan.resolve])."""
        require(0.0 <= self.share_fraction <= 1.0, "share_fraction", f"must be in [0, 1] (got {self.share_fraction})")
        require(self.share_tasks >= 1, "share_tasks", f"must be >= 1 (got {self.share_tasks})")
        require(self.hipi_temperature > 0, "hipi_temperature", f"must be > 0 (got {self.hipi_temperature})")
        require(
            0.0 <= self.conservative_percentile <= 100.0,
            "conservative_percentile",
            f"must be in [0, 100] (got {self.conservative_percentile})",
        )
