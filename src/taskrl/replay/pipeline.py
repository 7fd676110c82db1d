"""How a training batch is made: a draw picks rows, the replay gathers them, stages rewrite them.

    rows  = draw.rows(n, generator)            which (episode, step) rows, and the task each row trains
    batch = replay.gather(rows)                the stored transitions
    batch = stage(batch, rows, generator)      for each stage in turn

Draws (one protocol, `Draw`): `UniformDraw` over every stored transition;
[`TaskBalancedSampler`][taskrl.replay.sampling.TaskBalancedSampler] (the same share for every task);
[`TaskSharing`][taskrl.sharing.strategies.TaskSharing] (a sharing strategy picks other tasks' rows for each task
and marks the task they train); [`RecentMixSampler`][taskrl.replay.sampling.RecentMixSampler] (a share of the rows from
the newest episodes, the rest from any other draw). Stages (`Stage`): ``TaskSharing.to_task`` (rows
drawn for another task get that task's index, reward and termination) and hindsight relabelling
([`HindsightRelabeler`][taskrl.replay.hindsight.HindsightRelabeler] through `hindsight_stage`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Protocol

import torch

from taskrl.replay.batch import Batch
from taskrl.replay.storage import EpisodeReplay

__all__ = ["Draw", "Rows", "SamplerPipeline", "Stage", "UniformDraw", "hindsight_stage"]


@dataclasses.dataclass(frozen=True)
class Rows:
    """Rows a draw picked.

    Attributes:
        episode: ``[n]`` stored episode of each row.
        step: ``[n]`` step within it.
        task: ``[n]`` the task each row trains, ``-1`` for the task it was collected for; None: all their own.
        zero_reward: ``[n]`` rows whose reward becomes 0 (UDS's shared rows); None: none.
    """

    episode: torch.Tensor
    step: torch.Tensor
    task: torch.Tensor | None = None
    zero_reward: torch.Tensor | None = None

    @staticmethod
    def cat(parts: Sequence[Rows]) -> Rows:
        """The rows of ``parts`` one after the other (rows without a task keep their own)."""

        def column(name: str, fill: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor | None:
            if all(getattr(p, name) is None for p in parts):
                return None
            return torch.cat([getattr(p, name) if getattr(p, name) is not None else fill(p.episode) for p in parts])

        return Rows(
            torch.cat([p.episode for p in parts]),
            torch.cat([p.step for p in parts]),
            column("task", lambda e: torch.full_like(e, -1)),
            column("zero_reward", lambda e: torch.zeros_like(e, dtype=torch.bool)),
        )


class Draw(Protocol):
    """Picks the rows of a batch."""

    def rows(self, n: int, generator: torch.Generator | None = None) -> Rows:
        """``n`` rows; a ``RuntimeError`` while the replay holds no finished episode."""
        ...


class Stage(Protocol):
    """Rewrites a gathered batch (relabelling); ``rows`` are the rows it was gathered from."""

    def __call__(self, batch: Batch, rows: Rows, generator: torch.Generator | None) -> Batch: ...


class UniformDraw:
    """Rows uniform over every stored transition."""

    def __init__(self, replay: EpisodeReplay) -> None:
        self.replay = replay

    def rows(self, n: int, generator: torch.Generator | None = None) -> Rows:
        return Rows(*self.replay.sample_indices(n, generator))


def hindsight_stage(relabel: Callable[[Batch, EpisodeReplay, torch.Generator | None], Batch], replay: EpisodeReplay) -> Stage:
    """Hindsight relabelling (``relabel(batch, replay, generator)``) as a stage."""

    def stage(batch: Batch, rows: Rows, generator: torch.Generator | None) -> Batch:
        return relabel(batch, replay, generator)

    return stage


class SamplerPipeline:
    """``sampler(batch_size, generator) -> Batch``: ``draw``'s rows, gathered, then each of ``stages`` in turn.

    Args:
        replay: the episode storage.
        draw: picks the rows (`Draw`).
        stages: rewrite the gathered batch, in order (`Stage`).
    """

    def __init__(self, replay: EpisodeReplay, draw: Draw, stages: Sequence[Stage] = ()) -> None:
        self.replay, self.draw, self.stages = replay, draw, tuple(stages)

    def __call__(self, batch_size: int, generator: torch.Generator | None = None) -> Batch:
        rows = self.draw.rows(batch_size, generator)
        batch = self.replay.gather(rows.episode, rows.step)
        for stage in self.stages:
            batch = stage(batch, rows, generator)
        return batch
