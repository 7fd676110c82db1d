"""The on-policy loop: collect a rollout from batched environments -> one agent update -> repeat.

Each iteration steps all ``num_envs`` environments ``agent.rollout_steps`` times with the current
policy's samples, recording what the agent needs to compute returns (log-probabilities and
values at collection time, the value of ``info["final_obs"]`` where a time limit cut an episode,
and the value of the observation after the last step), and hands the :class:`Rollout` to
``agent.update``. Nothing is kept between rollouts. Evaluation, logging and checkpointing run on
env-step schedules, checked after each rollout, with the counters and the stopwatch of the
off-policy loop (:class:`~taskrl.training.offpolicy.LoopState`, ``Stopwatch``).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Protocol

import torch

from taskrl.envs.base import BatchedEnv, Obs
from taskrl.training.offpolicy import LoopState, Stopwatch


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
        final_value = torch.where(truncated, agent.value(info["final_obs"]), torch.zeros_like(value))
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
    ) -> None:
        self.env, self.agent, self.schedule, self.evaluate = env, agent, schedule, evaluate
        self.on_log, self.on_checkpoint = on_log, on_checkpoint
        self.generator = generator

    def run(self, state: LoopState, env_seed: int) -> LoopState:
        s, env, agent = self.schedule, self.env, self.agent
        obs = env.reset(seed=env_seed)
        # Sums of the agent's update metrics, kept as tensors between log rows: no host sync
        # inside the hot loop.
        metric_sums: dict[str, torch.Tensor] = {}
        episodes_done = torch.zeros((), device=env.device)
        episodes_success = torch.zeros((), device=env.device)
        row_updates, row_steps, row_rollouts = 0, 0, 0
        clock = Stopwatch(state.wall_seconds)
        row_start = clock.read()

        while state.env_steps < s.total_steps:
            rollout, obs, ended, succeeded = collect_rollout(env, agent, obs, agent.rollout_steps, self.generator)
            episodes_done += ended
            episodes_success += succeeded
            state.env_steps += rollout.num_steps
            row_steps += rollout.num_steps

            before = agent.updates
            for name, value in agent.update(rollout, self.generator).items():
                metric_sums[name] = metric_sums[name] + value if name in metric_sums else value.clone()
            state.updates += agent.updates - before
            row_updates += agent.updates - before
            row_rollouts += 1

            finished = state.env_steps >= s.total_steps
            if state.env_steps >= state.next_eval or finished:
                state.wall_seconds = clock.pause()
                elapsed = max(state.wall_seconds - row_start, 1e-9)
                result = self.evaluate()
                row = {
                    "env_steps": state.env_steps,
                    "updates": state.updates,
                    "wall_seconds": round(state.wall_seconds, 3),
                    **result,
                    "train_success": (episodes_success / episodes_done.clamp(min=1)).item(),
                    **{name: (total / max(row_rollouts, 1)).item() for name, total in metric_sums.items()},
                    "env_steps_per_s": row_steps / elapsed,
                    "updates_per_s": row_updates / elapsed,
                }
                self.on_log(row)
                state.last_success = result["success_rate"]
                state.best_success = max(state.best_success, result["success_rate"])
                missed = (state.env_steps - state.next_eval) // s.eval_interval + 1  # whole rollouts may skip some
                state.next_eval += max(missed, 1) * s.eval_interval
                metric_sums.clear(), episodes_done.zero_(), episodes_success.zero_()
                row_updates, row_steps, row_rollouts, row_start = 0, 0, 0, state.wall_seconds
                clock.resume()
                if s.stop_at_success > 0 and result["success_rate"] >= s.stop_at_success:
                    finished = True
            if state.env_steps >= state.next_checkpoint or finished:
                state.wall_seconds = clock.pause()
                state.next_checkpoint = state.env_steps + s.checkpoint_interval
                self.on_checkpoint(state)
                clock.resume()
            if finished:
                break
        state.wall_seconds = clock.pause()
        return state
