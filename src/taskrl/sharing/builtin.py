"""The built-in sharing strategies: weights ``w_j(e)`` of other tasks' episodes, and CDS's filter.

all, zero-reward   w_j(e) = 1
random             w_j(e) = 1 if task(e) is one of k tasks drawn for j in this batch, else 0
success            w_j(e) = 1 if some s' of e passes success_j (MT-Opt's task impersonation), else 0
hipi               w_j(e) = q(j | e) = softmax_j(R_j(e) / T - log Z_j),  log Z_j = logsumexp_e' R_j(e') / T
conservative       w_j(e) = 1, then a shared row is kept only if Q_j(s, a) >= P_k{Q_j(s~, a~)} (CDS)
"""

from __future__ import annotations

import dataclasses
import math

import torch

from taskrl.errors import require
from taskrl.sharing.strategy import Sampler, SharingStrategy

__all__ = ["BUILT_IN", "ConservativeSettings", "HIPISettings", "RandomSettings"]


@dataclasses.dataclass
class RandomSettings:
    """Settings of ``random`` sharing.

    Attributes:
        share_tasks: how many other tasks each task draws from.
    """

    share_tasks: int = 1

    def validate(self) -> None:
        require(self.share_tasks >= 1, "share_tasks", f"must be >= 1 (got {self.share_tasks})")


@dataclasses.dataclass
class HIPISettings:
    """Settings of ``hipi`` sharing.

    Attributes:
        hipi_temperature: the temperature of the posterior ``exp(R_j / T - log Z_j)``.
    """

    hipi_temperature: float = 1.0

    def validate(self) -> None:
        require(self.hipi_temperature > 0, "hipi_temperature", f"must be > 0 (got {self.hipi_temperature})")


@dataclasses.dataclass
class ConservativeSettings:
    """Settings of ``conservative`` sharing (CDS).

    Attributes:
        conservative_percentile: the percentile of the task's own rows' Q-values a shared row must reach (rows that do
            not are replaced by the task's own data).
    """

    conservative_percentile: float = 50.0

    def validate(self) -> None:
        require(
            0.0 <= self.conservative_percentile <= 100.0,
            "conservative_percentile",
            f"must be in [0, 100] (got {self.conservative_percentile})",
        )


def random_tasks(sharing: Sampler, source: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    """1 on the episodes of ``share_tasks`` other tasks drawn anew for each task and batch."""
    T, tasks = sharing.num_tasks, sharing.tasks
    k = min(sharing.settings.strategy_settings.share_tasks, T - 1)
    draw = torch.rand((T, T), generator=generator, device=source.device)
    draw[tasks, tasks] = 2.0  # never its own task
    chosen = torch.zeros(T, T, device=source.device).scatter_(1, draw.argsort(1)[:, :k], 1.0)
    return chosen[:, source]


def successful(sharing: Sampler, source: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    """1 on the episodes that pass the task's success test somewhere."""
    sharing.scores.refresh()
    return sharing.scores.success.t().float()


def hipi_posterior(sharing: Sampler, source: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    """The inverse-RL posterior ``q(j | e)`` of HIPI, with its partition term."""
    sharing.scores.refresh()
    stored = sharing.replay.length > 0
    logits = sharing.scores.returns / sharing.settings.strategy_settings.hipi_temperature  # [E, T]
    log_z = torch.logsumexp(logits.masked_fill(~stored[:, None], -math.inf), 0)  # [T]
    return torch.softmax(logits - log_z, 1).t()


def q_at_least_own_percentile(sharing: Sampler, own_episode, own_step, shared_episode, shared_step, has_own):
    """``[T, n]``: whether each shared candidate's Q under its task reaches the task's percentile of its own
    rows (always, for a task with no data of its own to compare with)."""
    threshold = torch.quantile(
        sharing.q_under_task(own_episode, own_step), sharing.settings.strategy_settings.conservative_percentile / 100.0, dim=1
    )
    threshold = threshold.masked_fill(~has_own, -math.inf)
    return sharing.q_under_task(shared_episode, shared_step) >= threshold[:, None]


BUILT_IN: tuple[SharingStrategy, ...] = (
    SharingStrategy("none", "own data only (task-balanced)", shares=False),
    SharingStrategy("all", "any other task's data, relabelled with this task's reward"),
    SharingStrategy(
        "random", "the data of share_tasks other tasks drawn for every batch", weights=random_tasks, settings=RandomSettings
    ),
    SharingStrategy(
        "success", "other tasks' episodes that pass this task's success test (MT-Opt)", weights=successful, needs_scores=True
    ),
    SharingStrategy(
        "hipi",
        "other tasks' episodes weighted by the inverse-RL posterior (HIPI)",
        weights=hipi_posterior,
        needs_scores=True,
        settings=HIPISettings,
    ),
    SharingStrategy(
        "conservative",
        "other tasks' rows whose Q under this task reaches its own rows' percentile (CDS)",
        keep=q_at_least_own_percentile,
        needs_q_value=True,
        settings=ConservativeSettings,
    ),
    SharingStrategy("zero-reward", "any other task's data with reward 0 (UDS)", zero_reward=True),
)
