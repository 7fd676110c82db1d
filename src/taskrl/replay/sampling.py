"""Samplers over stored episodes: task-balanced, and a mix of all data with the most recent episodes.

Task-balanced sampling: every task gets the same share of a batch, whatever its share of the data.

Uniform sampling over transitions lets the tasks that produce the most data (more copies, longer
episodes, a uniform task draw that happened to favour them) dominate the gradient. Multi-task SAC
on Meta-World samples ``batch_size / T`` transitions of every task instead. Episodes carry one
task each (the task of their first observation), so a task's transitions are the transitions of
its episodes; all tasks are drawn in one vectorised pass (a batched binary search over per-task
cumulative episode lengths, the episodes ordered by task), no Python loop over tasks.
"""

from __future__ import annotations

import torch

from taskrl.replay.batch import Batch
from taskrl.replay.pipeline import Draw, Rows, UniformDraw
from taskrl.replay.storage import EpisodeReplay, draw_transitions

__all__ = ["RecentMixSampler", "TaskBalancedSampler"]


class TaskBalancedSampler:
    """``sampler(batch_size, generator) -> Batch`` with ``batch_size // T`` transitions of every task.

    The remainder ``batch_size % T`` goes to the lowest task indices, one each. A task with no stored
    transition yet (early in a run, with tasks drawn at random) gets transitions drawn uniformly from
    all stored data instead, so the batch size never changes.

    The stored episodes are ordered by task once per change of the replay (``replay.version``); every
    batch is then one batched binary search over their cumulative lengths.

    Args:
        replay: the episode storage (observations must carry ``task_key``).
        num_tasks: T.
        task_key: observation key of the task index.
    """

    def __init__(self, replay: EpisodeReplay, num_tasks: int, task_key: str = "task") -> None:
        if task_key not in replay.obs_keys:
            raise ValueError(f"task-balanced sampling needs observations with a {task_key!r} key; found {replay.obs_keys}")
        if num_tasks < 1:
            raise ValueError(f"num_tasks: must be >= 1 (got {num_tasks})")
        self.replay, self.num_tasks, self.task_key = replay, int(num_tasks), task_key
        self._tasks = torch.arange(num_tasks, device=replay.device)
        self._version = -1
        self._by_task: tuple[torch.Tensor, ...] = ()

    def by_task(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(episodes, lengths, cumulative, first, totals)``: the stored episodes ordered by task (oldest
        first within a task), their lengths and cumulative lengths, and per task where its transitions
        start in that order and how many it has (``[T]``)."""
        r = self.replay
        if self._version != r.version:
            episodes = r.stored_episodes()
            task = r.observation_at(self.task_key, episodes, 0).long()
            order = torch.argsort(task, stable=True)
            episodes, task = episodes[order], task[order]
            lengths = r.length.index_select(0, episodes)
            totals = torch.zeros(self.num_tasks + 1, dtype=torch.long, device=r.device)
            totals.index_add_(0, task.clamp(0, self.num_tasks), lengths)  # out-of-range tasks: a last bin
            totals = totals[: self.num_tasks]
            first = torch.cumsum(totals, 0) - totals
            self._by_task = (episodes, lengths, torch.cumsum(lengths, 0), first, totals)
            self._version = r.version
        return self._by_task

    def indices(self, batch_size: int, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``(episode, step)`` index tensors, task-major: rows of task 0 first, then task 1, ..."""
        r, T = self.replay, self.num_tasks
        if r.num_episodes == 0:  # a count on the host: no device sync per batch
            raise RuntimeError("cannot sample from an empty replay: no episode has finished yet")
        episodes, lengths, cumulative, first, totals = self.by_task()
        empty = totals == 0  # empty task -> all data
        first = first.masked_fill(empty, 0)
        totals = torch.where(empty, r.num_transitions, totals)
        per = -(-batch_size // T)  # ceil
        u = torch.rand((T, per), generator=generator, device=r.device)
        target = first[:, None] + (u * totals[:, None]).long().minimum(totals[:, None] - 1)  # [T, per] positions
        at = torch.searchsorted(cumulative, target, right=True)
        step = target - (cumulative[at] - lengths[at])
        episode = episodes[at]
        # exactly batch_size rows: cut in step-major order (the remainder falls on the lowest task
        # indices), then back to task-major order
        flat = torch.arange(T * per, device=r.device).view(T, per).t().reshape(-1)[:batch_size].sort().values
        return episode.reshape(-1)[flat], step.reshape(-1)[flat]

    def rows(self, n: int, generator: torch.Generator | None = None) -> Rows:
        """`indices` as a [`Draw`][taskrl.replay.pipeline.Draw]."""
        return Rows(*self.indices(n, generator))

    def __call__(self, batch_size: int, generator: torch.Generator | None = None) -> Batch:
        return self.replay.gather(*self.indices(batch_size, generator))


class RecentMixSampler:
    """A [`Draw`][taskrl.replay.pipeline.Draw]: a fixed share of each batch from the most recent
    episodes (the "on-policy" window), the rest from another draw over everything stored (the
    "off-policy" store: uniform, task-balanced, or a sharing strategy's).

    QT-Opt trains on a mix of its store of all past grasps and a buffer of fresh on-policy data
    (Kalashnikov et al., 2018, sec. 4.2); with data preloaded from an earlier run (``--offline-data``)
    the window keeps new experience from being drowned by the old. Rows of the window come first.

    Args:
        replay: the episode storage.
        recent_fraction: share of each batch drawn from the window, in [0, 1].
        recent_episodes: the window: this many most recently stored episodes.
        rest: the draw for the rest of the batch (default uniform over all stored transitions); rows
            of the window train the task they were collected for.
    """

    def __init__(self, replay: EpisodeReplay, recent_fraction: float, recent_episodes: int, rest: Draw | None = None) -> None:
        if not 0.0 <= recent_fraction <= 1.0:
            raise ValueError(f"recent_fraction: must be in [0, 1] (got {recent_fraction})")
        if recent_episodes < 1:
            raise ValueError(f"recent_episodes: must be >= 1 (got {recent_episodes})")
        self.replay, self.recent_fraction, self.recent_episodes = replay, recent_fraction, recent_episodes
        self.rest = rest if rest is not None else UniformDraw(replay)

    def recent_indices(self, n: int, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``n`` transitions uniform over the window's transitions."""
        episodes = self.replay.newest_episodes(self.recent_episodes)
        lengths = self.replay.length[episodes]
        at, step = draw_transitions(lengths.cumsum(0), lengths, n, generator)
        return episodes[at], step

    def rows(self, n: int, generator: torch.Generator | None = None) -> Rows:
        """The window's rows first, then the rest's."""
        if self.replay.num_episodes == 0:
            raise RuntimeError("cannot sample from an empty replay: no episode has finished yet")
        n_recent = round(n * self.recent_fraction)
        return Rows.cat([Rows(*self.recent_indices(n_recent, generator)), self.rest.rows(n - n_recent, generator)])

    def __call__(self, batch_size: int, generator: torch.Generator | None = None) -> Batch:
        rows = self.rows(batch_size, generator)
        return self.replay.gather(rows.episode, rows.step)
