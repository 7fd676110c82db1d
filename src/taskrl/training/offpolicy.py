"""The off-policy loop: collect from batched environments -> store episodes -> relabel -> update.

One iteration asks the agent for exploratory actions (``agent.act(obs, explore=True)``: each
algorithm explores its own way), steps all ``num_envs`` environments once, stores the step, then
performs ``updates_per_step * num_envs`` gradient updates (fractions carry over), each on a freshly
sampled and relabelled batch. Evaluation, logging and checkpointing run on env-step schedules
([`Bookkeeping`][taskrl.training.bookkeeping.Bookkeeping], given to the loop).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Protocol

import torch

from taskrl.envs.base import BatchedEnv
from taskrl.replay.batch import Batch
from taskrl.replay.storage import EpisodeReplay
from taskrl.training.bookkeeping import Bookkeeping, LoopState
from taskrl.training.scripted import ScriptedExploration
from taskrl.types import Obs

__all__ = ["LoopSchedule", "LoopState", "OffPolicyLoop", "batch_sampler"]


class OffPolicyAgent(Protocol):
    def act(
        self, obs: Obs, explore: bool = False, generator: torch.Generator | None = None, env_steps: int = 0
    ) -> torch.Tensor: ...
    def exploration(self, env_steps: int) -> dict[str, float]: ...
    def update(self, batch: Batch) -> dict[str, torch.Tensor]: ...
    def update_many(self, batch: Batch, k: int) -> list[dict[str, torch.Tensor]]: ...


def batch_sampler(
    sample: Callable[[int, torch.Generator], Batch], batch_size: int, generator: torch.Generator
) -> Callable[[], Batch]:
    """``() -> Batch``: a batch of ``batch_size`` from ``sample`` (the run's
    [`SamplerPipeline`][taskrl.replay.pipeline.SamplerPipeline]: drawn, gathered and relabelled)."""

    def sample_batch() -> Batch:
        return sample(batch_size, generator)

    return sample_batch


@dataclasses.dataclass
class LoopSchedule:
    """When learning happens, in environment steps (evaluation and checkpoints: the Bookkeeping's).

    Attributes:
        total_steps: environment steps to train for.
        batch_size: transitions per gradient update.
        learning_starts: environment steps collected before the first update.
        updates_per_step: gradient updates per environment step (fractions accumulate).
        offline_updates: gradient updates on preloaded data before the first env step.
        scripted_exploration: share of training episodes the env's scripted policy acts
            ([`ScriptedExploration`][taskrl.training.scripted.ScriptedExploration]); 0: none.
        scripted_steps: env steps during which episodes may be scripted (0: the whole run).
        updates_per_call: updates handed to the agent at once (``agent.update_many``; one compiled graph
            for all of them under ``--compile``), each on its own batch: the ``k`` batches are drawn and
            relabelled as one of ``k * batch_size`` rows (each row drawn independently, so they are as ``k``
            draws are, for about one batch's small tensor operations) and split by the agent
            ([`split`][taskrl.replay.batch.Batch.split]); the update credit waits until it holds that many.
    """

    total_steps: int
    batch_size: int
    learning_starts: int
    updates_per_step: float
    offline_updates: int = 0
    updates_per_call: int = 1
    scripted_exploration: float = 0.0
    scripted_steps: int = 0


class OffPolicyLoop:
    """Runs collection and learning until ``total_steps`` or the bookkeeping says the run is finished.

    Args:
        env: training environments.
        agent: anything with ``act``, ``exploration`` and ``update``.
        replay: episode storage shared by collection and sampling.
        sample: ``sample(batch_size, generator) -> Batch`` drawing from ``replay`` and relabelling (a
            [`SamplerPipeline`][taskrl.replay.pipeline.SamplerPipeline]; ``replay.sample`` is uniform, unrelabelled).
        schedule: step counts for learning.
        books: the run's bookkeeping (metric rows, evaluation, early stop, checkpoints).
        generator: generator for sampling and exploration.
    """

    def __init__(
        self,
        env: BatchedEnv,
        agent: OffPolicyAgent,
        replay: EpisodeReplay,
        sample: Callable[[int, torch.Generator], Batch],
        schedule: LoopSchedule,
        books: Bookkeeping,
        generator: torch.Generator,
    ) -> None:
        self.env, self.agent, self.replay = env, agent, replay
        self.sample_batch = batch_sampler(sample, schedule.batch_size, generator)
        # one batch of k x batch_size rows, split by the agent
        self.sample_k_batches = batch_sampler(sample, schedule.batch_size * schedule.updates_per_call, generator)
        self.schedule, self.books, self.generator = schedule, books, generator
        self.scripted = (
            ScriptedExploration(env, schedule.scripted_exploration, schedule.scripted_steps, generator)
            if schedule.scripted_exploration > 0
            else None
        )

    def run(self, env_seed: int) -> LoopState:
        s, env, agent, replay, books = self.schedule, self.env, self.agent, self.replay, self.books
        state = books.state
        obs = env.reset(seed=env_seed)
        replay.start(obs)
        books.on_finish = replay.cut_running  # a stop or the end keeps the episodes still running
        while state.updates < s.offline_updates:  # learning from preloaded data first (--offline-data)
            books.add_update(agent.update(self.sample_batch()))
            if books.after_step(agent.exploration(0)):
                return books.close()
        while state.env_steps < s.total_steps:
            acted_at = state.env_steps
            action = agent.act(obs, explore=True, generator=self.generator, env_steps=acted_at)
            if self.scripted is not None:
                action = self.scripted.act(obs, action)
            next_obs, reward, terminated, truncated, info = env.step(action)
            replay.add(action, reward, terminated, truncated, info["final_obs"], next_obs)
            done = terminated | truncated
            books.add_episodes(done, done & info["is_success"])
            books.add_steps(env.num_envs)
            if self.scripted is not None:
                self.scripted.episodes_ended(done, state.env_steps)
            obs = next_obs

            if state.env_steps >= s.learning_starts and replay.num_episodes > 0:
                state.update_credit += env.num_envs * s.updates_per_step
                k = s.updates_per_call
                n_updates = int(state.update_credit // k) * k
                state.update_credit -= n_updates
                if k == 1:
                    for _ in range(n_updates):
                        books.add_update(agent.update(self.sample_batch()))
                else:
                    for _ in range(n_updates // k):
                        for metrics in agent.update_many(self.sample_k_batches(), k):
                            books.add_update(metrics)

            if books.after_step(agent.exploration(acted_at)):  # the level this step explored with
                break
        return books.close()
