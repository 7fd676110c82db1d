"""The off-policy loop: collect from batched environments -> store episodes -> relabel -> update.

One iteration steps all ``num_envs`` environments once, stores the step, then performs
``updates_per_step * num_envs`` gradient updates (fractions carry over), each on a freshly
sampled and relabelled batch. Evaluation, logging and checkpointing run on env-step schedules.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Protocol

import torch

from taskrl.envs.base import BatchedEnv, Obs
from taskrl.replay.batch import Batch
from taskrl.replay.episodes import EpisodeReplay
from taskrl.training.bookkeeping import Bookkeeping, LoopState, StopRequest

__all__ = ["LoopSchedule", "LoopState", "OffPolicyLoop"]


class OffPolicyAgent(Protocol):
    def act(self, obs: Obs, epsilon: float = 0.0, generator: torch.Generator | None = None) -> torch.Tensor: ...
    def update(self, batch: Batch) -> dict[str, torch.Tensor]: ...


Relabel = Callable[[Batch, EpisodeReplay, torch.Generator], Batch]


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
        stop: ends the run early and cleanly (a time limit, Ctrl-C); its ``stopped_by`` says why.
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
        stop: StopRequest | None = None,
        sample: Callable[[int, torch.Generator], Batch] | None = None,
    ) -> None:
        self.env, self.agent, self.replay, self.relabel = env, agent, replay, relabel
        self.sample = sample if sample is not None else replay.sample
        self.schedule, self.evaluate = schedule, evaluate
        self.on_log, self.on_checkpoint = on_log, on_checkpoint
        self.generator = generator
        self.stop = stop

    def sample_batch(self) -> Batch:
        batch = self.sample(self.schedule.batch_size, self.generator)
        return self.relabel(batch, self.replay, self.generator) if self.relabel else batch

    def run(self, state: LoopState, env_seed: int) -> LoopState:
        s, env, agent, replay = self.schedule, self.env, self.agent, self.replay
        books = Bookkeeping(state, self.evaluate, self.on_log, self.on_checkpoint, s.total_steps, s.eval_interval,
                            s.checkpoint_interval, s.stop_at_success, env.device, self.stop)
        obs = env.reset(seed=env_seed)
        replay.start(obs)
        while state.env_steps < s.total_steps:
            epsilon = s.epsilon(state.env_steps)
            action = agent.act(obs, epsilon, self.generator)
            next_obs, reward, terminated, truncated, info = env.step(action)
            replay.add(action, reward, terminated, truncated, info["final_obs"], next_obs)
            done = terminated | truncated
            books.add_episodes(done, done & info["is_success"])
            books.add_steps(env.num_envs)
            obs = next_obs

            if state.env_steps >= s.learning_starts and replay.num_episodes > 0:
                state.update_credit += env.num_envs * s.updates_per_step
                n_updates = int(state.update_credit)
                state.update_credit -= n_updates
                for _ in range(n_updates):
                    books.add_update(agent.update(self.sample_batch()))

            if books.after_step({"epsilon": epsilon}):
                break
        return books.close()
