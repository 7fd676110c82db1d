"""Cross-task data sharing: each task's rows of a batch drawn from its own data and, by a strategy,
from other tasks' data relabelled with its reward.

For a batch of B rows and T tasks, task j gets ``n = ceil(B / T)`` rows (cut back to B as the
task-balanced sampler does): ``n - m`` from the episodes collected for j, ``m = round(share_fraction * n)``
from episodes collected for other tasks i != j, and every row is then scored under j::

    s_task, s'_task <- j,   r <- r_j(s, a, s'),   terminated <- success_j(s') or failure_j(s')

(a strategy with ``zero_reward``, UDS, instead keeps ``r = 0`` and no termination on the shared rows: it
labels data of unknown reward with the lowest reward.) A transition is drawn from a set of episodes uniformly
over its transitions: episode e with weight ``len(e) * w_j(e)``, then a step uniformly. A strategy
([`SharingStrategy`][taskrl.sharing.strategy.SharingStrategy], registered in [`taskrl.sharing.registry`][taskrl.sharing.registry]) hooks in at
three points: the weight ``w_j(e)`` of another task's episode e, a filter on the shared rows once drawn (a row
not kept is replaced by one of j's own), and the reward of shared rows. The built-in ones are in
[`taskrl.sharing.builtin`][taskrl.sharing.builtin]:

    all, zero-reward   w_j(e) = 1
    random             w_j(e) = 1 if task(e) is one of k tasks drawn for j in this batch, else 0
    success            w_j(e) = 1 if some s' of e passes success_j (MT-Opt's task impersonation), else 0
    hipi               w_j(e) = q(j | e) = softmax_j(R_j(e) / T - log Z_j),  log Z_j = logsumexp_e' R_j(e') / T
                       (the inverse-RL posterior of HIPI, with its partition term, R_j the return under r_j)
    conservative       w_j(e) = 1, then a shared row is kept only if Q_j(s, a) >= P_k{Q_j(s~, a~)}, the
                       k-th percentile over the batch's own rows of j (CDS)

A task with no data of its own gets all its rows from others; a strategy that finds nothing to share
for j (no episode passes success_j yet) gives j its own data only; a task with neither (early in a
run, or ``none`` and no data yet) lends its rows to data of any task, left as it is. ``none`` is task-balanced sampling
of own data. How much of each task's rows came from which task is counted (`TaskSharing.metrics`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch

from taskrl.replay.batch import Batch
from taskrl.replay.pipeline import Rows
from taskrl.replay.storage import EpisodeReplay
from taskrl.sharing.registry import sharing_strategy
from taskrl.sharing.settings import SharingConfig
from taskrl.sharing.strategy import SharingStrategy
from taskrl.types import Obs

__all__ = ["EpisodeScores", "TaskSharing", "task_functions"]

QValue = Callable[[Obs, torch.Tensor], torch.Tensor]
SCORE_CHUNK = 2048  # episodes scored at once


def task_functions(env: Any) -> bool:
    """Whether ``env`` scores transitions under any task (``task_reward``, ``task_terminated``, ``task_success``)."""
    return all(callable(getattr(env, name, None)) for name in ("task_reward", "task_terminated", "task_success"))


class EpisodeScores:
    """Per stored episode and task: whether some ``s'`` passes the task's success test, and the return
    under its reward. Scored once per episode, when it is first seen (all again when the replay lays its
    episodes out anew).

    Args:
        replay: the episode storage.
        env: the env whose ``task_reward`` and ``task_success`` score them.
        num_tasks: T.
    """

    def __init__(self, replay: EpisodeReplay, env: Any, num_tasks: int) -> None:
        self.replay, self.env, self.num_tasks = replay, env, num_tasks
        self.seen, self.layout = 0, -1

    def refresh(self) -> None:
        r = self.replay
        if self.layout != r.layout:  # new episode ids: score every stored episode
            self.success = torch.zeros(r.episode_slots, self.num_tasks, dtype=torch.bool, device=r.device)
            self.returns = torch.zeros(r.episode_slots, self.num_tasks, device=r.device)
            self.layout, self.seen = r.layout, r.episodes_added - r.num_episodes
        new = min(r.episodes_added - self.seen, r.num_episodes)
        self.seen = r.episodes_added
        if new <= 0:
            return
        for chunk in r.newest_episodes(new).split(SCORE_CHUNK):
            self._score(chunk)

    def _score(self, episodes: torch.Tensor) -> None:
        r = self.replay
        episode, step = r.episode_steps(episodes)
        batch = r.gather(episode, step)
        row = torch.arange(episodes.numel(), device=r.device).repeat_interleave(r.length[episodes])
        for j in range(self.num_tasks):
            task = torch.full_like(episode, j)
            success = self.env.task_success(batch.next_obs, task).float()
            reward = self.env.task_reward(batch.obs, batch.action, batch.next_obs, task).float()
            self.success[episodes, j] = torch.zeros(episodes.numel(), device=r.device).index_add_(0, row, success) > 0
            self.returns[episodes, j] = torch.zeros(episodes.numel(), device=r.device).index_add_(0, row, reward)


class TaskSharing:
    """``sampler(batch_size, generator) -> Batch``: rows for every task from its own and shared data.

    Args:
        replay: the episode storage (observations carry ``task_key``).
        env: scores rows under any task: ``task_reward(obs, action, next_obs, task)``,
            ``task_terminated(next_obs, task)``, ``task_success(next_obs, task)``.
        num_tasks: T.
        settings: the strategy and its knobs ([`SharingConfig`][taskrl.sharing.settings.SharingConfig]).
        q_value: for a strategy that ``needs_q_value`` (``conservative``): ``q_value(obs, action) -> [B]``, the
            agent's Q of each row under the row's task (no gradient).
        task_key: the observation key of the task index.
        strategy: the strategy (default the registered one that ``settings.sharing`` names).
    """

    def __init__(
        self,
        replay: EpisodeReplay,
        env: Any,
        num_tasks: int,
        settings: SharingConfig,
        q_value: QValue | None = None,
        task_key: str = "task",
        strategy: SharingStrategy | None = None,
    ) -> None:
        if not task_functions(env):
            raise ValueError(
                "data sharing needs an env whose tasks are reward functions: task_reward, task_terminated, task_success"
            )
        self.strategy = strategy if strategy is not None else sharing_strategy(settings.sharing)
        if self.strategy.needs_q_value and q_value is None:
            raise ValueError(f"{self.strategy.name} sharing compares Q-values of the agent: pass q_value")
        self.replay, self.env, self.num_tasks, self.settings = replay, env, int(num_tasks), settings
        self.q_value, self.task_key = q_value, task_key
        self.tasks = torch.arange(self.num_tasks, device=replay.device)
        self.scores = EpisodeScores(replay, env, self.num_tasks) if self.strategy.needs_scores else None
        self.counts = torch.zeros(self.num_tasks, self.num_tasks, device=replay.device)  # [target, source] rows

    # ------------------------------------------------------------------ weights
    def shared_weights(self, source: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        """``w_j(e)`` of every task j and stored episode e of another task, ``[T, E]`` (0 on own episodes)."""
        other = (source[None] != self.tasks[:, None]).float()  # [T, E]
        if self.strategy.weights is None:
            return other
        return other * self.strategy.weights(self, source, generator)

    # ------------------------------------------------------------------ drawing
    def _draw(self, weights: torch.Tensor, n: int, generator: torch.Generator | None) -> tuple[torch.Tensor, torch.Tensor]:
        """``[T, n]`` episodes (by weight) and steps (uniform within each episode)."""
        episode = torch.multinomial(weights, n, replacement=True, generator=generator)
        length = self.replay.length[episode]
        step = (torch.rand(episode.shape, generator=generator, device=episode.device) * length).long().minimum(length - 1)
        return episode, step

    def relabel(self, batch: Batch, task: torch.Tensor, zero_reward: torch.Tensor | None = None) -> Batch:
        """``batch`` as data of ``task[row]``: task index, reward ``r_j``, termination under j; rows in
        ``zero_reward`` get reward 0 and no termination."""
        obs = {**batch.obs, self.task_key: task.to(batch.obs[self.task_key].dtype)}
        next_obs = {**batch.next_obs, self.task_key: obs[self.task_key]}
        reward = self.env.task_reward(obs, batch.action, next_obs, task).to(batch.reward.dtype)
        terminated = self.env.task_terminated(next_obs, task)
        if zero_reward is not None:
            reward = reward.masked_fill(zero_reward, 0.0)
            terminated = terminated & ~zero_reward
        return batch.replace(
            obs=obs, next_obs=next_obs, reward=reward, terminated=terminated, truncated=batch.truncated & ~terminated
        )

    def __call__(self, batch_size: int, generator: torch.Generator | None = None) -> Batch:
        """A batch on its own: `rows`, gathered, then `to_task` (what the run's pipeline does)."""
        rows = self.rows(batch_size, generator)
        return self.to_task(self.replay.gather(rows.episode, rows.step), rows, generator)

    def to_task(self, batch: Batch, rows: Rows, generator: torch.Generator | None = None) -> Batch:
        """The pipeline stage after `rows`: each row as data of the task it trains (its own where
        ``rows.task`` is -1, e.g. rows of a recent window), reward 0 where ``rows.zero_reward``."""
        own = batch.obs[self.task_key].long()
        task = own if rows.task is None else torch.where(rows.task >= 0, rows.task, own)
        return self.relabel(batch, task, rows.zero_reward)

    def rows(self, n: int, generator: torch.Generator | None = None) -> Rows:
        """``n`` rows (a [`Draw`][taskrl.replay.pipeline.Draw]): ``n / T`` for every task, a strategy's share of
        them from other tasks' data, each marked with the task it trains."""
        batch_size = n
        r, T, s = self.replay, self.num_tasks, self.settings
        if r.num_episodes == 0:
            raise RuntimeError("cannot sample from an empty replay: no episode has finished yet")
        per = -(-batch_size // T)
        length = r.length.float()
        source = r.first_observations(self.task_key).long().masked_fill(r.length == 0, 0)  # [E]
        own = length * (source[None] == self.tasks[:, None])  # [T, E]
        shared = length * self.shared_weights(source, generator) if self.strategy.shares else torch.zeros_like(own)
        has_own, has_shared = own.sum(1) > 0, shared.sum(1) > 0
        n_shared = torch.where(has_shared, torch.where(has_own, round(s.share_fraction * per), per), 0)  # [T]
        # a task with neither its own data nor any to share: rows from all data, with their own tasks
        # (as task-balanced sampling does)
        own_episode, own_step = self._draw(torch.where(has_own[:, None], own, length[None]), per, generator)
        shared_episode, shared_step = self._draw(torch.where(has_shared[:, None], shared, length[None]), per, generator)
        column = torch.arange(per, device=r.device)
        from_shared = column[None] < n_shared[:, None]  # [T, per]
        if self.strategy.keep is not None:
            from_shared = from_shared & self.strategy.keep(self, own_episode, own_step, shared_episode, shared_step, has_own)
        episode = torch.where(from_shared, shared_episode, own_episode)
        step = torch.where(from_shared, shared_step, own_step)
        # exactly batch_size rows: cut in step-major order (the remainder falls on the lowest tasks)
        flat = torch.arange(T * per, device=r.device).view(T, per).t().reshape(-1)[:batch_size].sort().values
        episode, step, from_shared = episode.reshape(-1)[flat], step.reshape(-1)[flat], from_shared.reshape(-1)[flat]
        target = self.tasks.repeat_interleave(per)[flat]
        # a task with neither its own data nor any to share lends its rows to the data drawn, as they are
        lent = ~(has_own | has_shared)[target]
        target = torch.where(lent, source[episode], target)
        self.counts.index_put_((target, source[episode]), torch.ones_like(target, dtype=torch.float), accumulate=True)
        return Rows(episode, step, target, from_shared if self.strategy.zero_reward else None)

    def q_under_task(self, episode: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """``[T, n]`` Q-values of the rows at ``(episode, step)`` ``[T, n]``, row t scored under task t."""
        task = self.tasks[:, None].expand_as(episode).reshape(-1)
        batch = self.relabel(self.replay.gather(episode.reshape(-1), step.reshape(-1)), task)
        with torch.no_grad():
            return self.q_value(batch.obs, batch.action).view(episode.shape)

    # ------------------------------------------------------------------ statistics
    def metrics(self, names: list[str]) -> dict[str, float]:
        """Since the last call: ``shared/<task>``, the share of the task's rows from other tasks' data,
        and ``from/<task>``, the share of all rows whose data was collected for the task."""
        counts = self.counts.to("cpu", copy=True)
        self.counts.zero_()
        total = counts.sum()
        if float(total) == 0:
            return {}
        rows = counts.sum(1).clamp(min=1)
        own = counts.diagonal()
        out = {"shared_fraction": float(1 - own.sum() / total)}
        out.update({f"shared/{n}": float(1 - own[j] / rows[j]) for j, n in enumerate(names)})
        out.update({f"from/{n}": float(counts[:, j].sum() / total) for j, n in enumerate(names)})
        return out
