"""MT-Opt's sharing with negatives: other tasks' episodes that pass this task's success test and those that do
not, rebalanced per task so each half weighs the same.

For task j, with S_j the other tasks' stored episodes that pass success_j somewhere and F_j the rest,

    w_j(e) = 1 / |S_j|_steps  (e in S_j),   1 / |F_j|_steps  (e in F_j)

where |.|_steps counts transitions, so that, drawn by ``len(e) * w_j(e)``, half of j's shared rows come from
successes and half from failures under j's reward (all from one half when the other is empty). ``success``
shares the successes only; failures relabelled with j's reward are the negatives MT-Opt adds.
"""

from __future__ import annotations

import torch

from taskrl.sharing.strategy import Sampler, SharingStrategy

__all__ = ["MTOPT"]


def successes_and_failures(sharing: Sampler, source: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
    sharing.scores.refresh()
    length = sharing.replay.length.float()[None]  # [1, E]
    other = (source[None] != sharing.tasks[:, None]).float() * (length > 0)  # [T, E]
    success = sharing.scores.success.t().float() * other
    failure = (1.0 - sharing.scores.success.t().float()) * other
    steps_s = (success * length).sum(1, keepdim=True)
    steps_f = (failure * length).sum(1, keepdim=True)
    return success / steps_s.clamp(min=1.0) + failure / steps_f.clamp(min=1.0)


MTOPT = SharingStrategy(
    "mtopt",
    "other tasks' successes and failures under this task, half and half (MT-Opt's negatives)",
    weights=successes_and_failures,
    needs_scores=True,
)
