"""Pieces every agent shares, so each agent's file holds only its own algorithm.

- :class:`ObservationInput`: the network input (chosen observation keys -> float -> running
  normalisation), one module for the online and target networks alike;
- :class:`ActionBox`: between an action box ``[low, high]`` and the ``[-1, 1]^A`` networks see;
- :func:`gradient_step`: zero the gradients, backpropagate, clip the norm, step;
- :func:`as_batch`: one numpy observation of a gymnasium environment as a batch of one;
- :func:`explore_in_box`: the hindsight paper's exploration for deterministic policies.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn

from taskrl.agents.cem import action_bounds
from taskrl.nets import ObsConcat
from taskrl.normalization import RunningNorm
from taskrl.replay.batch import Obs


class ObservationInput(nn.Module):
    """``obs -> [keys concatenated, as float] -> (x - mean) / std`` (clipped), or no normalisation.

    Args:
        keys: observation keys the networks read, e.g. ``("observation", "desired_goal")``.
        dim: total flattened size of those keys.
        normalize: standardise with running statistics from the training batches.
    """

    def __init__(self, keys: Sequence[str], dim: int, normalize: bool) -> None:
        super().__init__()
        self.encode = ObsConcat(keys)
        self.normalize = RunningNorm(dim) if normalize else nn.Identity()

    def forward(self, obs: Obs) -> torch.Tensor:
        return self.normalize(self.encode(obs))

    def update_statistics(self, obs: Obs) -> None:
        """Merge a training batch into the running statistics (no-op without normalisation)."""
        if isinstance(self.normalize, RunningNorm):
            self.normalize.update(self.encode(obs))


class ActionBox:
    """An action box ``[low, high]`` and its affine map to and from ``[-1, 1]^A``.

    Args:
        action_space: a gymnasium ``Box`` or a ``(low, high)`` pair.
        device: where the bounds live.
    """

    def __init__(self, action_space: Any, device: str | torch.device) -> None:
        self.low, self.high = action_bounds(action_space, device)
        self.dim = self.low.numel()
        self.center, self.half = (self.high + self.low) / 2, (self.high - self.low) / 2

    def to_unit(self, action: torch.Tensor) -> torch.Tensor:
        """Box -> [-1, 1] (what the networks see)."""
        return (action.float() - self.center) / self.half

    def from_unit(self, unit: torch.Tensor) -> torch.Tensor:
        """[-1, 1] -> box."""
        return self.center + self.half * unit


def gradient_step(optimizer: torch.optim.Optimizer, loss: torch.Tensor, params: list[torch.Tensor], max_grad_norm: float) -> None:
    """``zero_grad -> backward -> clip_grad_norm (if max_grad_norm > 0) -> step``."""
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    if max_grad_norm > 0:
        nn.utils.clip_grad_norm_(params, max_grad_norm, foreach=True)
    optimizer.step()


def as_batch(obs: Obs | dict[str, Any], device: torch.device) -> tuple[Obs, bool]:
    """``(batched obs, single)``: one numpy observation becomes a batch of one on ``device``."""
    single = any(isinstance(v, np.ndarray) for v in obs.values())
    if single:
        obs = {k: torch.as_tensor(np.asarray(v), device=device).unsqueeze(0) for k, v in obs.items()}
    return obs, single


def explore_in_box(unit: torch.Tensor, noise_std: float, random_prob: float,
                   generator: torch.Generator | None = None) -> torch.Tensor:
    """Exploration around deterministic actions in ``[-1, 1]^A`` (the hindsight paper's, for Fetch):

        a = clip(a* + N(0, noise_std^2), -1, 1)     Gaussian noise, in half-widths of the box
        a = U(-1, 1)^A  with probability random_prob per row   (the paper: 0.2 noise, 30% random)
    """
    n, dim = unit.shape
    if noise_std > 0:
        unit = (unit + noise_std * torch.randn(unit.shape, generator=generator, device=unit.device)).clamp(-1.0, 1.0)
    if random_prob > 0:
        pick = torch.rand(n, 1, generator=generator, device=unit.device) < random_prob
        uniform = torch.rand(n, dim, generator=generator, device=unit.device) * 2 - 1
        unit = torch.where(pick, uniform, unit)
    return unit
