"""What a data-sharing strategy declares: which hook it uses and what it needs (``docs/sharing.md``)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Protocol

import torch

from taskrl.errors import require
from taskrl.replay.storage import EpisodeReplay

__all__ = ["Keep", "Sampler", "SharingStrategy", "Weights"]


class Sampler(Protocol):
    """What a strategy's hooks may read of the task-sharing sampler
    ([`TaskSharing`][taskrl.sharing.strategies.TaskSharing])."""

    replay: EpisodeReplay
    settings: Any  # the run's SharingConfig; the strategy's own settings are its ``strategy_settings``
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
        settings: its own settings, a dataclass with a ``validate()`` (None: it has none): the command line's flags
            while it is the run's ``--sharing`` (``--data-sharing.NAME.FIELD``, or the field's short name), the hooks
            read them as ``sampler.settings.strategy_settings``.
    """

    name: str
    summary: str
    shares: bool = True
    weights: Weights | None = None
    keep: Keep | None = None
    zero_reward: bool = False
    needs_scores: bool = False
    needs_q_value: bool = False
    settings: type | None = None

    def check(self, sampling: str, family: Any, algorithm: Any, env_label: str, rewarded_envs: str, ranked_algos: str) -> None:
        """What this strategy needs of the run, as the env ``family`` (an ``EnvFamily``: its ``task_rewards``) and the
        ``algorithm`` (an ``AlgorithmSpec``: its ``q_values``) declare it: tasks that are reward functions, an agent
        with Q-values where it ranks rows by them, task-balanced batches (``sampling``). ``env_label`` names the env;
        ``rewarded_envs`` and ``ranked_algos`` list what would fit, for the message."""
        if not self.shares:
            return
        require(
            family.task_rewards is not False,
            "sharing",
            f"needs an env whose tasks are reward functions (task_reward, task_terminated, task_success); "
            f"{env_label!r} has none; allowed envs: {rewarded_envs}",
        )
        require(
            not self.needs_q_value or algorithm.q_values,
            "sharing",
            f"{self.name} ranks shared data by Q-values; {algorithm.name} has no q_value; use {ranked_algos}",
        )
        require(
            sampling == "task_balanced",
            "sampling",
            "data sharing draws every task's rows of a batch (task-balanced): use --sampling task_balanced",
        )
