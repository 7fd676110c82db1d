"""Small network building blocks shared by the agents."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from taskrl.replay.batch import Obs


def mlp(in_dim: int, hidden_sizes: Sequence[int], out_dim: int, activation: type[nn.Module] = nn.ReLU) -> nn.Sequential:
    """``Linear -> activation`` for each hidden size, then a final ``Linear`` to ``out_dim``."""
    layers: list[nn.Module] = []
    for size in hidden_sizes:
        layers += [nn.Linear(in_dim, size), activation()]
        in_dim = size
    layers.append(nn.Linear(in_dim, out_dim))
    return nn.Sequential(*layers)


class ObsConcat(nn.Module):
    """Flattens the chosen observation keys to float and concatenates them: ``[s, g]``.

    A goal-conditioned Q-function sees the state and the desired goal; the achieved goal is
    usually part of the state and left out.
    """

    def __init__(self, keys: Sequence[str]) -> None:
        super().__init__()
        self.keys = tuple(keys)

    def forward(self, obs: Obs) -> torch.Tensor:
        parts = [obs[k].flatten(1) for k in self.keys]
        if len({p.dtype for p in parts}) == 1:  # one cast after the concat: fewer small ops
            return torch.cat(parts, dim=1).float()
        return torch.cat([p.float() for p in parts], dim=1)
