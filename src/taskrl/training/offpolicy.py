"""The off-policy loop: collect from batched environments -> store episodes -> relabel -> update.

One iteration steps all ``num_envs`` environments once, stores the step, then performs
``updates_per_step * num_envs`` gradient updates (fractions carry over), each on a freshly
sampled and relabelled batch. Evaluation, logging and checkpointing run on env-step schedules.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Callable, Protocol

import torch

from taskrl.envs.base import BatchedEnv, Obs
from taskrl.replay.batch import Batch
from taskrl.replay.episodes import EpisodeReplay


class OffPolicyAgent(Protocol):
    def act(self, obs: Obs, epsilon: float = 0.0, generator: torch.Generator | None = None) -> torch.Tensor: ...
    def update(self, batch: Batch) -> dict[str, torch.Tensor]: ...


Relabel = Callable[[Batch, EpisodeReplay, torch.Generator], Batch]


class Stopwatch:
    """Training wall-clock that can be paused (evaluation and checkpoints do not count)."""

    def __init__(self, already: float = 0.0) -> None:
        self.total, self.started = already, time.perf_counter()

    def pause(self) -> float:
        self.total += time.perf_counter() - self.started
        return self.total

    def resume(self) -> None:
        self.started = time.perf_counter()

    def read(self) -> float:
        return self.total + time.perf_counter() - self.started


@dataclasses.dataclass
class LoopSchedule:
    """When things happen, in environment steps."""

    total_steps: int
    batch_size: int
    learning_starts: int
    updates_per_step: float
    eval_interval: int
    checkpoint_interval: int
    stop_at_success: float = 0.0
    epsilon_start: float = 0.0
    epsilon_end: float = 0.0
    epsilon_decay_steps: int = 0

    def epsilon(self, env_steps: int) -> float:
        """Linear decay from ``epsilon_start`` to ``epsilon_end`` over ``epsilon_decay_steps``."""
        if self.epsilon_decay_steps <= 0:
            return self.epsilon_end
        frac = min(env_steps / self.epsilon_decay_steps, 1.0)
        return self.epsilon_start + frac * (self.epsilon_end - self.epsilon_start)


@dataclasses.dataclass
class LoopState:
    """Counters that survive a resume."""

    env_steps: int = 0
    updates: int = 0
    wall_seconds: float = 0.0
    update_credit: float = 0.0
    next_eval: int = 0
    next_checkpoint: int = 0
    best_success: float = 0.0
    last_success: float = 0.0


class OffPolicyLoop:
    """Runs collection and learning until ``total_steps`` or ``stop_at_success``.

    Args:
        env: training environments.
        agent: anything with ``act`` and ``update``.
        replay: episode storage shared by collection and sampling.
        relabel: optional ``relabel(batch, replay, generator)`` applied to every sampled batch.
        schedule: step counts for learning, evaluation and checkpoints.
        evaluate: ``() -> metrics`` run on the evaluation schedule (must return ``success_rate``).
        on_log: called with each metrics row (to CSV, TensorBoard, the console).
        on_checkpoint: called with the loop state when a checkpoint is due.
        generator: generator for sampling and exploration.
        sample: ``sample(batch_size, generator) -> Batch`` drawing from ``replay`` (default
            ``replay.sample``: uniform over transitions; e.g. a ``TaskBalancedSampler``).
    """

    def __init__(
        self,
        env: BatchedEnv,
        agent: OffPolicyAgent,
        replay: EpisodeReplay,
        relabel: Relabel | None,
        schedule: LoopSchedule,
        evaluate: Callable[[], dict[str, float]],
        on_log: Callable[[dict[str, Any]], None],
        on_checkpoint: Callable[[LoopState], None],
        generator: torch.Generator,
        sample: Callable[[int, torch.Generator], Batch] | None = None,
    ) -> None:
        self.env, self.agent, self.replay, self.relabel = env, agent, replay, relabel
        self.sample = sample if sample is not None else replay.sample
        self.schedule, self.evaluate = schedule, evaluate
        self.on_log, self.on_checkpoint = on_log, on_checkpoint
        self.generator = generator

    def sample_batch(self) -> Batch:
        batch = self.sample(self.schedule.batch_size, self.generator)
        return self.relabel(batch, self.replay, self.generator) if self.relabel else batch

    def run(self, state: LoopState, env_seed: int) -> LoopState:
        s, env, agent, replay = self.schedule, self.env, self.agent, self.replay
        obs = env.reset(seed=env_seed)
        replay.start(obs)
        # Sums of the agent's update metrics, kept as tensors between log rows: no host sync
        # inside the hot loop.
        metric_sums: dict[str, torch.Tensor] = {}
        episodes_done = torch.zeros((), device=env.device)
        episodes_success = torch.zeros((), device=env.device)
        row_updates, row_steps = 0, 0
        clock = Stopwatch(state.wall_seconds)
        row_start = clock.read()

        while state.env_steps < s.total_steps:
            epsilon = s.epsilon(state.env_steps)
            action = agent.act(obs, epsilon, self.generator)
            next_obs, reward, terminated, truncated, info = env.step(action)
            replay.add(action, reward, terminated, truncated, info["final_obs"], next_obs)
            done = terminated | truncated
            episodes_done += done.sum()
            episodes_success += (done & info["is_success"]).sum()
            obs = next_obs
            state.env_steps += env.num_envs
            row_steps += env.num_envs

            if state.env_steps >= s.learning_starts and replay.num_episodes > 0:
                state.update_credit += env.num_envs * s.updates_per_step
                n_updates = int(state.update_credit)
                state.update_credit -= n_updates
                for _ in range(n_updates):
                    for name, value in agent.update(self.sample_batch()).items():
                        metric_sums[name] = metric_sums[name] + value if name in metric_sums else value.clone()
                state.updates += n_updates
                row_updates += n_updates

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
                    **{name: (total / max(row_updates, 1)).item() for name, total in metric_sums.items()},
                    "epsilon": epsilon,
                    "env_steps_per_s": row_steps / elapsed,
                    "updates_per_s": row_updates / elapsed,
                }
                self.on_log(row)
                state.last_success = result["success_rate"]
                state.best_success = max(state.best_success, result["success_rate"])
                state.next_eval += s.eval_interval
                metric_sums.clear(), episodes_done.zero_(), episodes_success.zero_()
                row_updates, row_steps, row_start = 0, 0, state.wall_seconds
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
