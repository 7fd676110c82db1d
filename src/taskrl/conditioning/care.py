"""CARE: contextual attention-based representations (Sodhani, Zhang, Pineau, ICML 2021).

k state encoders, mixed by attention weights computed from the task context (in CARE, a frozen
sentence embedding of the task description):

    z_j(s) = f_j(s)                                   j = 1..k   (k MLPs on the state)
    w(c)   = softmax(g(c) / temperature)              g: an MLP, w in the k-simplex
    z      = sum_j w_j(c) z_j(s)                      the mixed encoding
    out    = [z, c]                                   fed to SAC's actor and critics

Each encoder layer holds the k members' weights as one ``[k, in, out]`` parameter (``ParallelLinear``).
The mixture runs the encoders one at a time (``CAREEncoder.encoding``): at MT10's scale (batch 1280,
width 400) one encoder's activations are 2 MB, which stay in cache through its layers, where the k run
as one batched matmul (8 MB at k = 4) did not (``benchmarks/per_call_costs.py``, "CARE encoders").
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from taskrl.nets import activation_after, mlp

__all__ = ["CAREEncoder", "ParallelLinear"]


class ParallelLinear(nn.Module):
    """k independent linear layers in one batched matmul.

    ``[B, in]`` (the same input for every member) or ``[k, B, in]`` -> ``[k, B, out]``. Each member is
    initialised as ``nn.Linear`` is: ``U(-1/sqrt(in), 1/sqrt(in))`` for weights and biases.
    """

    def __init__(self, k: int, in_dim: int, out_dim: int) -> None:
        super().__init__()
        self.k, self.in_dim, self.out_dim = k, in_dim, out_dim
        self.weight = nn.Parameter(torch.empty(k, in_dim, out_dim))
        self.bias = nn.Parameter(torch.empty(k, 1, out_dim))
        bound = 1.0 / math.sqrt(in_dim)
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.dim() == 2:
            return torch.matmul(x, self.weight) + self.bias  # [B, in] @ [k, in, out] -> [k, B, out]
        return torch.baddbmm(self.bias, x, self.weight)

    def member(self, x: torch.Tensor, j: int) -> torch.Tensor:
        """Member ``j`` alone: ``[B, in] -> [B, out]``, ``x W_j + b_j`` as one product with its bias."""
        return torch.addmm(self.bias[j], x, self.weight[j])

    def extra_repr(self) -> str:
        return f"k={self.k}, in_dim={self.in_dim}, out_dim={self.out_dim}"


class CAREEncoder(nn.Module):
    """Mixture of k state encoders weighted by attention on the context; output ``[z, c]``.

    Args:
        state_dim: width of the state ``s [B, state_dim]``.
        context_dim: width of the context ``c [B, context_dim]`` (e.g. a ``LanguageTaskEncoder``'s).
        num_encoders: k (CARE uses 4 to 6).
        encoder_hidden: hidden widths of each state encoder.
        output_dim: width of each encoding (and of the mixed encoding ``z``).
        attention_hidden: hidden widths of the attention MLP ``g``.
        temperature: softmax temperature of the attention.
        activation: activation class of the encoders and of ``g``.

    Attributes:
        out_dim: ``output_dim + context_dim``, the width of the output.
    """

    def __init__(
        self,
        state_dim: int,
        context_dim: int,
        num_encoders: int = 6,
        encoder_hidden: Sequence[int] = (256,),
        output_dim: int = 64,
        attention_hidden: Sequence[int] = (64,),
        temperature: float = 1.0,
        activation: type[nn.Module] = nn.ReLU,
    ) -> None:
        super().__init__()
        if num_encoders < 1:
            raise ValueError(f"num_encoders: must be >= 1 (got {num_encoders})")
        if temperature <= 0:
            raise ValueError(f"temperature: must be > 0 (got {temperature})")
        self.num_encoders, self.temperature = int(num_encoders), float(temperature)
        self.state_dim, self.context_dim, self.output_dim = int(state_dim), int(context_dim), int(output_dim)
        self.out_dim = self.output_dim + self.context_dim
        layers: list[nn.Module] = []
        in_dim = state_dim
        for size in encoder_hidden:
            layer = ParallelLinear(num_encoders, in_dim, size)
            layers += [layer, activation_after(layer, activation)]
            in_dim = size
        layers.append(ParallelLinear(num_encoders, in_dim, output_dim))
        self.encoders = nn.Sequential(*layers)
        self.attention = mlp(context_dim, tuple(attention_hidden), num_encoders, activation)

    def attention_weights(self, context: torch.Tensor) -> torch.Tensor:
        """``w(c) = softmax(g(c) / temperature)``: ``[B, k]``, each row sums to 1."""
        return torch.softmax(self.attention(context) / self.temperature, dim=-1)

    def encodings(self, state: torch.Tensor) -> torch.Tensor:
        """All k encodings ``z_j(s)``: ``[k, B, output_dim]`` (as one batched matmul per layer)."""
        return self.encoders(state)

    def encoding(self, state: torch.Tensor, j: int) -> torch.Tensor:
        """Encoding ``z_j(s)`` of encoder ``j`` alone: ``[B, output_dim]``."""
        h = state
        for layer in self.encoders:
            h = layer.member(h, j) if isinstance(layer, ParallelLinear) else layer(h)
        return h

    def forward(self, state: torch.Tensor, context: torch.Tensor, return_weights: bool = False):
        """``[z, c]`` of shape ``[B, output_dim + context_dim]``; with ``return_weights``, also ``w [B, k]``."""
        if state.shape[0] != context.shape[0]:
            raise ValueError(f"state and context: batch sizes differ ({state.shape[0]} vs {context.shape[0]})")
        weights = self.attention_weights(context)
        mixed = weights[:, :1] * self.encoding(state, 0)  # z = sum_j w_j z_j, one encoder at a time (module docstring)
        for j in range(1, self.num_encoders):
            mixed = mixed + weights[:, j : j + 1] * self.encoding(state, j)
        out = torch.cat([mixed, context], dim=-1)
        return (out, weights) if return_weights else out
