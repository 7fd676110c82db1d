"""What a data-sharing strategy declares: which hook it uses and what it needs (``docs/sharing.md``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Protocol

import torch

from taskrl.replay.storage import EpisodeReplay
from taskrl.sharing.settings import SharingConfig

__all__ = ["Keep", "Sampler", "SharingStrategy", "Weights"]


class Sampler(Protocol):
    """What a strategy's hooks may read of the task-sharing sampler
    ([`TaskSharing`][taskrl.sharing.strategies.TaskSharing])."""

    replay: EpisodeReplay
    settings: SharingConfig
    num_tasks: int
    tasks: torch.Tensor  # [T] task indices
    scores: Any  # EpisodeScores (success and return of every stored episode under every task), when needed

    def q_under_task(self, episode: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """``[T, n]`` Q-values of the rows at ``(episode, step)``, row t scored under task t."""
        ...


#: ``(sampler, source task of every stored episode [E], generator) -> w_j(e)`` ``[T, E]``, before other-task masking.
Weights = Callable[[Sampler, torch.Tensor, "torch.Generator | None"], torch.Tensor]
#: ``(sampler, own episodes, own steps, shared episodes, shared steps, has_own [T]) -> keep [T, n]``: which drawn
#: shared rows stay (a row not kept is replaced by one of the task's own).
Keep = Callable[[Sampler, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]


@dataclasses.dataclass(frozen=True)
class SharingStrategy:
    """One way of sharing data between tasks, at up to three hooks of the task-sharing sampler.

    Register one with [`taskrl.sharing.registry.register_sharing_strategy`][taskrl.sharing.registry.register_sharing_strategy]; ``--sharing NAME`` uses it.

    Attributes:
        name: the value of ``--sharing``.
        summary: one line on what it shares.
        shares: False for the strategy that shares nothing (plain task-balanced draws of own data).
        weights: the weight ``w_j(e)`` of another task's episode e for task j (None: every episode weighs 1).
        keep: a filter on the shared rows once drawn (None: all stay).
        zero_reward: shared rows get reward 0 and no termination instead of the task's reward (UDS).
        needs_scores: every stored episode's success and return under every task (``sampler.scores``).
        needs_q_value: the agent's ``q_value(obs, action)`` (``sampler.q_value``); the algorithm must have one.
    """

    name: str
    summary: str
    shares: bool = True
    weights: Weights | None = None
    keep: Keep | None = None
    zero_reward: bool = False
    needs_scores: bool = False
    needs_q_value: bool = False
