"""The on-policy loop: collect a rollout from batched environments -> one agent update -> repeat.

Each iteration steps all ``num_envs`` environments ``agent.rollout_steps`` times with the current
policy's samples, recording what the agent needs to compute returns (log-probabilities and
values at collection time, the value of ``info["final_obs"]`` where a time limit cut an episode,
and the value of the observation after the last step), and hands the :class:`Rollout` to
``agent.update``. Nothing is kept between rollouts. Evaluation, logging and checkpointing run on
env-step schedules, checked after each rollout, with the counters and the stopwatch of the
off-policy loop (:class:`~taskrl.training.bookkeeping.Bookkeeping`).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Protocol

import torch

from taskrl.envs.base import BatchedEnv, Obs
from taskrl.training.bookkeeping import Bookkeeping, LoopState, StopRequest


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

    def explore(self, obs: Obs, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]: ...
    def value(self, obs: Obs) -> torch.Tensor: ...
    def update(self, rollout: Rollout, generator: torch.Generator | None = None) -> dict[str, torch.Tensor]: ...


@dataclasses.dataclass
class OnPolicySchedule:
    """When things happen, in environment steps (checked after every rollout, so a run takes
    whole rollouts: it may overshoot ``total_steps`` by less than one).

    Attributes:
        total_steps: environment steps to train for (summed over environments).
        eval_interval: environment steps between evaluations.
        checkpoint_interval: environment steps between checkpoints (also one at the end).
        stop_at_success: stop once evaluation success reaches this (0 = train to total_steps).
    """

    total_steps: int
    eval_interval: int
    checkpoint_interval: int
    stop_at_success: float = 0.0


def collect_rollout(env: BatchedEnv, agent: OnPolicyAgent, obs: Obs, steps: int,
                    generator: torch.Generator | None = None) -> tuple[Rollout, Obs, torch.Tensor, torch.Tensor]:
    """Step ``env`` ``steps`` times from ``obs`` with ``agent.explore``.

    Returns ``(rollout, next_obs, episodes_ended, episodes_succeeded)``; the counts are 0-d
    tensors (success is ``info["is_success"]`` at the step an episode ends).
    """
    columns: dict[str, list[torch.Tensor]] = {k: [] for k in ("action", "log_prob", "value", "reward", "terminated", "truncated", "final_value")}
    observations: list[Obs] = []
    ended = torch.zeros((), device=env.device)
    succeeded = torch.zeros((), device=env.device)
    for _ in range(steps):
        env_action, action, log_prob, value = agent.explore(obs, generator)
        next_obs, reward, terminated, truncated, info = env.step(env_action)
        final_value = torch.zeros_like(value)
        if bool(truncated.any()):  # time limits are rare steps: no value pass on the others
            final_value = torch.where(truncated, agent.value(info["final_obs"]), final_value)
        for key, item in (("action", action), ("log_prob", log_prob), ("value", value), ("reward", reward.float()),
                          ("terminated", terminated), ("truncated", truncated), ("final_value", final_value)):
            columns[key].append(item)
        observations.append(obs)
        done = terminated | truncated
        ended += done.sum()
        succeeded += (done & info["is_success"]).sum()
        obs = next_obs
    stacked = {key: torch.stack(items) for key, items in columns.items()}
    rollout = Rollout(obs={k: torch.stack([o[k] for o in observations]) for k in observations[0]},
                      last_value=agent.value(obs), **stacked)
    return rollout, obs, ended, succeeded


class OnPolicyLoop:
    """Runs collection and learning until ``total_steps`` or ``stop_at_success``.

    Args:
        env: training environments.
        agent: anything with ``rollout_steps``, ``updates``, ``explore``, ``value`` and ``update``
            (e.g. :class:`~taskrl.agents.ppo.PPOAgent`).
        schedule: step counts for evaluation and checkpoints.
        evaluate: ``() -> metrics`` run on the evaluation schedule (must return ``success_rate``).
        on_log: called with each metrics row (to CSV, TensorBoard, the console).
        on_checkpoint: called with the loop state when a checkpoint is due.
        stop: ends the run early and cleanly (a time limit, Ctrl-C); its ``stopped_by`` says why.
        generator: generator for action sampling and minibatch order.
    """

    def __init__(
        self,
        env: BatchedEnv,
        agent: OnPolicyAgent,
        schedule: OnPolicySchedule,
        evaluate: Callable[[], dict[str, float]],
        on_log: Callable[[dict[str, Any]], None],
        on_checkpoint: Callable[[LoopState], None],
        generator: torch.Generator,
        stop: StopRequest | None = None,
    ) -> None:
        self.env, self.agent, self.schedule, self.evaluate = env, agent, schedule, evaluate
        self.on_log, self.on_checkpoint = on_log, on_checkpoint
        self.generator = generator
        self.stop = stop

    def run(self, state: LoopState, env_seed: int) -> LoopState:
        s, env, agent = self.schedule, self.env, self.agent
        books = Bookkeeping(state, self.evaluate, self.on_log, self.on_checkpoint, s.total_steps, s.eval_interval,
                            s.checkpoint_interval, s.stop_at_success, env.device, self.stop)
        obs = env.reset(seed=env_seed)
        while state.env_steps < s.total_steps:
            rollout, obs, ended, succeeded = collect_rollout(env, agent, obs, agent.rollout_steps, self.generator)
            books.add_episodes(ended, succeeded)
            books.add_steps(rollout.num_steps)
            before = agent.updates
            metrics = agent.update(rollout, self.generator)
            books.add_update(metrics, gradient_steps=agent.updates - before)
            if books.after_step():
                break
        return books.close()
