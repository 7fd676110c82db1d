"""Running mean / standard-deviation normalisation of network inputs.

As in the hindsight paper's implementation: statistics are accumulated from the inputs the
learner trains on, inputs are standardised and then clipped to ``[-clip, clip]``. The statistics
are buffers, so they travel with ``state_dict`` into checkpoints.
"""

from __future__ import annotations

import torch
from torch import nn


class RunningNorm(nn.Module):
    """``(x - mean) / max(std, eps)``, clipped; ``update(x)`` merges a batch into the statistics.

    Args:
        dim: input width.
        clip: bound on the normalised values.
        eps: floor on the standard deviation (constant inputs stay finite).
        raw_columns: columns handed on as they come, neither standardised nor clipped (a position a network reads
            as a place in the picture: `taskrl.encoders.GlimpseInput`); their statistics are still kept.
    """

    def __init__(self, dim: int, clip: float = 5.0, eps: float = 1e-2, raw_columns: tuple[int, ...] = ()) -> None:
        super().__init__()
        self.clip, self.eps = clip, eps
        raw = None
        if raw_columns:
            raw = torch.zeros(dim, dtype=torch.bool)
            raw[list(raw_columns)] = True
        self.register_buffer("raw", raw, persistent=False)
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("var", torch.ones(dim))
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.register_buffer("inv_std", torch.ones(dim), persistent=False)

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Chan et al.'s parallel merge of batch moments into the running moments."""
        n = x.shape[0]
        batch_var, batch_mean = torch.var_mean(x, dim=0, unbiased=False)
        total = self.count + n
        delta = batch_mean - self.mean
        self.mean += delta * (n / total).float()
        m2 = self.var * self.count.float() + batch_var * n + delta.square() * (self.count * n / total).float()
        self.var.copy_(m2 / total.float())
        self.count.view(1).add_(n)  # = total; through a view: a compiled step loses writes to a 0-d float64 tensor (torch 2.13)
        self._refresh()

    def _refresh(self) -> None:
        torch.reciprocal(self.var.sqrt().clamp(min=self.eps), out=self.inv_std)

    def _load_from_state_dict(self, *args, **kwargs) -> None:
        super()._load_from_state_dict(*args, **kwargs)
        self._refresh()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        normalised = ((x - self.mean) * self.inv_std).clamp_(-self.clip, self.clip)
        return normalised if self.raw is None else torch.where(self.raw, x, normalised)
