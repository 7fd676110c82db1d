"""FiLM: feature-wise linear modulation of hidden layers by a task context (Perez et al., 2018).

    gamma(c), beta(c) = split(W c + b)          one linear layer, 2F outputs
    FiLM(h; c)        = (1 + gamma(c)) * h + beta(c)

``W`` and ``b`` start at zero, so at initialisation the scale is 1 and the shift 0 for every context:
FiLM is the identity and a `FiLMMLP` computes exactly the plain MLP it wraps. The context
then receives gradient from the second update on (once ``W`` has moved away from zero); the FiLM
parameters themselves receive gradient from the first.

`FiLMMLP` modulates every hidden layer before its activation, as BC-Z does in every block:

    h_0 = x,   h_l = act(FiLM_l(A_l h_{l-1} + a_l; c)),   y = A_out h_L + a_out
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from taskrl.nets import activation_after

__all__ = ["FiLM", "FiLMMLP"]


class FiLM(nn.Module):
    """``(1 + gamma(c)) * h + beta(c)`` with ``[gamma, beta] = Linear(context_dim, 2 * features)(c)``.

    Args:
        context_dim: width C of the context ``c [B, C]``.
        features: width F of the modulated features ``h [B, F]`` (or ``[B, ..., F]`` with the
            context broadcast over the middle dimensions).
    """

    def __init__(self, context_dim: int, features: int) -> None:
        super().__init__()
        self.features = int(features)
        self.generator = nn.Linear(context_dim, 2 * features)
        nn.init.zeros_(self.generator.weight)
        nn.init.zeros_(self.generator.bias)

    def scale_shift(self, context: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(gamma, beta)``, each ``[B, F]``; gamma is the full scale ``1 + delta``."""
        delta, beta = self.generator(context).chunk(2, dim=-1)
        return 1.0 + delta, beta

    def forward(self, h: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        gamma, beta = self.scale_shift(context)
        if h.dim() > gamma.dim():  # [B, ..., F]: broadcast over the middle dimensions
            shape = (gamma.shape[0],) + (1,) * (h.dim() - gamma.dim()) + (self.features,)
            gamma, beta = gamma.reshape(shape), beta.reshape(shape)
        return torch.addcmul(beta, gamma, h)


class FiLMMLP(nn.Module):
    """An MLP whose every hidden layer is FiLM-modulated by the context: ``forward(x, context) -> [B, out_dim]``.

    Args:
        in_dim: input width.
        hidden_sizes: widths of the hidden layers (each: Linear -> FiLM -> activation).
        out_dim: output width (a final Linear, not modulated).
        context_dim: width of the context.
        activation: activation class (default ``nn.ReLU``).
    """

    def __init__(
        self,
        in_dim: int,
        hidden_sizes: Sequence[int],
        out_dim: int,
        context_dim: int,
        activation: type[nn.Module] = nn.ReLU,
    ) -> None:
        super().__init__()
        self.linears = nn.ModuleList()
        self.films = nn.ModuleList()
        for size in hidden_sizes:
            self.linears.append(nn.Linear(in_dim, size))
            self.films.append(FiLM(context_dim, size))
            in_dim = size
        # after FiLM's fresh output (its backward does not need it): a ReLU in place, as nets.mlp's
        self.activation = activation_after(self.films[-1], activation) if self.films else activation()
        self.out = nn.Linear(in_dim, out_dim)
        self.context_dim, self.out_dim = int(context_dim), int(out_dim)

    def forward(self, x: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        for linear, film in zip(self.linears, self.films):
            x = self.activation(film(linear(x), context))
        return self.out(x)
