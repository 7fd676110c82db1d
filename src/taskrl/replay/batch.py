"""The batch every agent's ``update`` consumes: explicit keys, one loss for every kind of data."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import torch

from taskrl.types import Obs

__all__ = ["Batch", "Obs"]


@dataclasses.dataclass
class Batch:
    """A batch of transitions ``(s, a, r, s', terminated, truncated)``.

    ``obs`` and ``next_obs`` are dicts with the environment's observation keys (for goal-conditioned
    data ``observation``, ``achieved_goal``, ``desired_goal``). ``terminated`` means no bootstrap from
    ``next_obs``; ``truncated`` (a time limit) still bootstraps. ``episode`` and ``step`` locate
    each transition in the replay so relabellers can look up the rest of its episode.
    """

    obs: Obs
    action: torch.Tensor
    reward: torch.Tensor
    next_obs: Obs
    terminated: torch.Tensor
    truncated: torch.Tensor
    episode: torch.Tensor
    step: torch.Tensor

    def __len__(self) -> int:
        return self.reward.shape[0]

    def replace(self, **changes) -> Batch:
        return dataclasses.replace(self, **changes)

    def split(self, k: int) -> list[Batch]:
        """``k`` batches of ``len(self) // k`` rows: batch ``i`` holds rows ``i, i + k, i + 2k, ...``, so a
        batch drawn task by task (task-balanced, shared) splits into ``k`` batches that each keep its mix."""
        n = len(self) // k
        order = torch.arange(n * k, device=self.reward.device).view(n, k).t().reshape(-1)  # rows of batch 0, then 1, ...

        def parts(value: torch.Tensor | Obs) -> list:
            if isinstance(value, dict):
                split = {key: parts(v) for key, v in value.items()}
                return [{key: split[key][i] for key in value} for i in range(k)]
            return list(value.index_select(0, order).split(n))

        fields = {f.name: parts(getattr(self, f.name)) for f in dataclasses.fields(self)}
        return [Batch(**{name: values[i] for name, values in fields.items()}) for i in range(k)]

    @classmethod
    def interleave(cls, batches: Sequence[Batch]) -> Batch:
        """The one batch whose `split` into ``len(batches)`` gives ``batches`` back (rows ``i, i + k, ...``
        are ``batches[i]``'s): how ``k`` batches of equal size go to ``agent.update_many`` together."""

        def rows(values: list) -> torch.Tensor | Obs:
            if isinstance(values[0], dict):
                return {key: rows([v[key] for v in values]) for key in values[0]}
            return torch.stack(values, dim=1).flatten(0, 1)

        return cls(**{f.name: rows([getattr(b, f.name) for b in batches]) for f in dataclasses.fields(cls)})

    def to(self, device: str | torch.device) -> Batch:
        """This batch on ``device`` (itself when already there)."""
        device = torch.device(device)
        if self.reward.device == device:
            return self

        def moved(value: torch.Tensor | Obs) -> torch.Tensor | Obs:
            return {k: v.to(device) for k, v in value.items()} if isinstance(value, dict) else value.to(device)

        return Batch(**{f.name: moved(getattr(self, f.name)) for f in dataclasses.fields(self)})
