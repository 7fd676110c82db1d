"""Small network building blocks shared by the agents."""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from taskrl.types import Obs


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


class StateActionQ(nn.Module):
    """Q(x, a) = MLP([x, a]) -> one value per (state, action) pair.

    ``score_actions(x, actions)`` evaluates N actions for each of B states in one call. It splits
    the first layer, W [x; a] + b = (W_x x + b) + W_a a, so the state's share is computed once
    per state instead of once per sample and no [B * N, in] copy of the states is built.
    """

    def __init__(self, in_dim: int, action_dim: int, hidden_sizes: tuple[int, ...]) -> None:
        super().__init__()
        self.in_dim = in_dim
        self.body = mlp(in_dim + action_dim, hidden_sizes, 1)

    def forward(self, x: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """x [B, D], action [B, A] -> [B]."""
        return self.body(torch.cat([x, action], dim=-1)).squeeze(-1)

    def score_actions(self, x: torch.Tensor, actions: torch.Tensor, chunk_rows: int | None = None) -> torch.Tensor:
        """x [B, D], actions [B, N, A] -> [B, N]: Q(x_b, a_bn) for all B * N pairs, for ``no_grad`` use (CEM).

        On CPU the rows go through the network in chunks of about ``chunk_rows`` (default 2048 per
        torch thread): a chunk's activations (2048 x 256 floats = 2 MiB) stay in cache between
        layers, which measured 2x faster (one thread) than one pass over all 16384 rows of a
        256-state, 64-sample CEM round. On GPU, in a compiled step (or with ``chunk_rows=0``) it is one pass. Rows
        stay 2-D (a 3-D input makes ``Linear`` ~35% slower on CPU) and ReLUs run in place.
        """
        b, n, _ = actions.shape
        if chunk_rows is None:
            chunk_rows = 0 if x.is_cuda or torch.compiler.is_compiling() else 2048 * torch.get_num_threads()
        per_chunk = b if chunk_rows <= 0 else max(1, chunk_rows // n)
        if per_chunk >= b:
            return self._score(x, actions)
        return torch.cat([self._score(x[i : i + per_chunk], actions[i : i + per_chunk]) for i in range(0, b, per_chunk)])

    def _score(self, x: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        b, n, a = actions.shape
        first = self.body[0]
        state_part = F.linear(x, first.weight[:, : self.in_dim], first.bias)  # [b, H], once per state
        h = actions.reshape(b * n, a) @ first.weight[:, self.in_dim :].T  # [b * n, H]
        h.view(b, n, -1).add_(state_part.unsqueeze(1))
        for layer in self.body[1:]:
            h = h.relu_() if isinstance(layer, nn.ReLU) else layer(h)
        return h.view(b, n)
