"""The offline loop: learn from a fixed dataset, evaluate in the env, checkpoint; no env step while it trains.

One iteration draws a batch (``sample(batch_size, generator)``, e.g. a
[`DemoSampler`][taskrl.demos.sampling.DemoSampler]) and makes one gradient update. ``total_steps``,
``eval_interval`` and ``checkpoint_interval`` count gradient updates (the bookkeeping's ``updates``
axis); ``env_steps`` stays 0 in ``metrics.csv``, because training never steps an env.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch

from taskrl.training.bookkeeping import Bookkeeping, LoopState

__all__ = ["OfflineLoop"]


class OfflineLoop:
    """Runs ``total_updates`` gradient updates on sampled batches, with the run's bookkeeping.

    Args:
        agent: anything with ``update(batch) -> dict of scalars``.
        sample: ``(batch_size, generator) -> batch``.
        total_updates: gradient updates to make.
        batch_size: rows per update.
        books: the run's bookkeeping (on its ``updates`` axis).
        generator: generator for sampling.
    """

    def __init__(
        self,
        agent: Any,
        sample: Callable[[int, torch.Generator], Any],
        total_updates: int,
        batch_size: int,
        books: Bookkeeping,
        generator: torch.Generator,
    ) -> None:
        if books.axis != "updates":
            raise ValueError("an offline loop's bookkeeping counts updates (axis='updates')")
        self.agent, self.sample, self.total_updates, self.batch_size = agent, sample, total_updates, batch_size
        self.books, self.generator = books, generator

    def run(self, env_seed: int = 0) -> LoopState:
        """Train until ``total_updates`` (or an early stop); ``env_seed`` is unused (no env steps)."""
        books, state = self.books, self.books.state
        while state.updates < self.total_updates:
            books.add_update(self.agent.update(self.sample(self.batch_size, self.generator)))
            if books.after_step():
                break
        return books.close()
