"""A demonstration encoder: one demonstration of a task in, a task embedding out (BC-Z's video encoder, on states).

    h_l = ReLU(W s_l + b)                         each of the L frames (normalised states)
    g   = ReLU(Conv1d(ReLU(Conv1d(h))))           two temporal convolutions, kernel 3, over the frames
    z   = Linear(mean_l g_l)                      the embedding, ``out_dim`` wide

With language alignment (BC-Z's language-regression loss), ``out_dim`` is the sentence embedding's
width and ``z`` is pulled towards the task's sentence embedding by ``1 - cos(z, e_task)``, so a policy
conditioned on ``z`` can be prompted by a demonstration or by a sentence.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["DemoEncoder"]


class DemoEncoder(nn.Module):
    """``forward(frames [B, L, D]) -> [B, out_dim]``.

    Args:
        state_dim: width D of a state.
        out_dim: width of the embedding.
        hidden: width of the per-frame features and of the convolutions.
    """

    def __init__(self, state_dim: int, out_dim: int, hidden: int = 64) -> None:
        super().__init__()
        self.frame = nn.Sequential(nn.Linear(state_dim, hidden), nn.ReLU())
        self.temporal = nn.Sequential(
            nn.Conv1d(hidden, hidden, kernel_size=3, padding=1),
            nn.ReLU(),
            nn.Conv1d(hidden, hidden, kernel_size=3, padding=1),
            nn.ReLU(),
        )
        self.out = nn.Linear(hidden, out_dim)
        self.context_dim = int(out_dim)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        if frames.dim() != 3:
            raise ValueError(f"frames: expected [B, L, D] (got {tuple(frames.shape)})")
        h = self.frame(frames).transpose(1, 2)  # [B, hidden, L]
        return self.out(self.temporal(h).mean(dim=2))
