"""The on-policy loop: collect a rollout from batched environments -> one agent update -> repeat.

Each iteration steps all ``num_envs`` environments ``agent.rollout_steps`` times with the current
policy's samples, recording what the agent needs to compute returns (log-probabilities and
values at collection time, the value of ``info["final_obs"]`` where a time limit cut an episode,
and the value of the observation after the last step), and hands the `Rollout` to
``agent.update``. Nothing is kept between rollouts. Evaluation, logging and checkpointing run on
env-step schedules, checked after each rollout, with the counters and the stopwatch of the
off-policy loop ([`Bookkeeping`][taskrl.training.bookkeeping.Bookkeeping]).
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import torch

from taskrl.envs.base import BatchedEnv
from taskrl.training.bookkeeping import Bookkeeping, LoopState
from taskrl.types import Obs


@dataclasses.dataclass
class Rollout:
    """``T`` steps of ``N`` environments, every tensor ``[T, N, ...]`` (``last_value``: ``[N]``).

    Attributes:
        obs: observations the actions were taken in, by key.
        action: the policy's own samples (unclipped Gaussian samples in [-1, 1] units, or indices).
        log_prob: log pi_old(action | obs) at collection time.
        value: V(obs) at collection time.
        reward: rewards.
        terminated: true ends (no bootstrap).
        truncated: time-limit ends (bootstrap from ``final_value``).
        final_value: V(info["final_obs"]) where ``truncated``, 0 elsewhere.
        last_value: V of the observation after the last step (bootstraps the unfinished episodes).
    """

    obs: Obs
    action: torch.Tensor
    log_prob: torch.Tensor
    value: torch.Tensor
    reward: torch.Tensor
    terminated: torch.Tensor
    truncated: torch.Tensor
    final_value: torch.Tensor
    last_value: torch.Tensor

    @property
    def num_steps(self) -> int:
        """Transitions in the rollout, T x N."""
        return self.reward.numel()


class OnPolicyAgent(Protocol):
    rollout_steps: int
    updates: int

    def rollout_step(
        self, obs: Obs, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]: ...
    def value(self, obs: Obs) -> torch.Tensor: ...
    def update(self, rollout: Rollout, generator: torch.Generator | None = None) -> dict[str, torch.Tensor]: ...


def collect_rollout(
    env: BatchedEnv, agent: OnPolicyAgent, obs: Obs, steps: int, generator: torch.Generator | None = None
) -> tuple[Rollout, Obs, torch.Tensor, torch.Tensor]:
    """Step ``env`` ``steps`` times from ``obs`` with ``agent.rollout_step``.

    Returns ``(rollout, next_obs, episodes_ended, episodes_succeeded)``; the counts are 0-d
    tensors (success is ``info["is_success"]`` at the step an episode ends).
    """
    columns: dict[str, list[torch.Tensor]] = {
        k: [] for k in ("action", "log_prob", "value", "reward", "terminated", "truncated", "final_value")
    }
    observations: list[Obs] = []
    ended = torch.zeros((), device=env.device)
    succeeded = torch.zeros((), device=env.device)
    for _ in range(steps):
        env_action, action, log_prob, value = agent.rollout_step(obs, generator)
        next_obs, reward, terminated, truncated, info = env.step(env_action)
        final_value = torch.zeros_like(value)
        if bool(truncated.any()):  # time limits are rare steps: no value pass on the others
            final_value = torch.where(truncated, agent.value(info["final_obs"]), final_value)
        for key, item in (
            ("action", action),
            ("log_prob", log_prob),
            ("value", value),
            ("reward", reward.float()),
            ("terminated", terminated),
            ("truncated", truncated),
            ("final_value", final_value),
        ):
            columns[key].append(item)
        observations.append(obs)
        done = terminated | truncated
        ended += done.sum()
        succeeded += (done & info["is_success"]).sum()
        obs = next_obs
    stacked = {key: torch.stack(items) for key, items in columns.items()}
    rollout = Rollout(
        obs={k: torch.stack([o[k] for o in observations]) for k in observations[0]}, last_value=agent.value(obs), **stacked
    )
    return rollout, obs, ended, succeeded


class OnPolicyLoop:
    """Runs collection and learning until ``total_steps`` or the bookkeeping says the run is finished
    (checked after every rollout, so a run takes whole rollouts: it may overshoot ``total_steps``
    by less than one).

    Args:
        env: training environments.
        agent: anything with ``rollout_steps``, ``updates``, ``rollout_step``, ``value`` and ``update``
            (e.g. [`PPOAgent`][taskrl.agents.ppo.PPOAgent]).
        total_steps: environment steps to train for (summed over environments).
        books: the run's bookkeeping (metric rows, evaluation, early stop, checkpoints).
        generator: generator for action sampling and minibatch order.
    """

    def __init__(
        self, env: BatchedEnv, agent: OnPolicyAgent, total_steps: int, books: Bookkeeping, generator: torch.Generator
    ) -> None:
        self.env, self.agent, self.total_steps, self.books, self.generator = env, agent, total_steps, books, generator

    def run(self, env_seed: int) -> LoopState:
        env, agent, books = self.env, self.agent, self.books
        state = books.state
        obs = env.reset(seed=env_seed)
        while state.env_steps < self.total_steps:
            rollout, obs, ended, succeeded = collect_rollout(env, agent, obs, agent.rollout_steps, self.generator)
            books.add_episodes(ended, succeeded)
            books.add_steps(rollout.num_steps)
            before = agent.updates
            metrics = agent.update(rollout, self.generator)
            books.add_update(metrics, gradient_steps=agent.updates - before)
            if books.after_step():
                break
        return books.close()
