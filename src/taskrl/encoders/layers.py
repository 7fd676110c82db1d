"""The convolution every picture encoder is made of, initialised as DrQ's (or as PyTorch's, for behaviour cloning)."""

from __future__ import annotations

from torch import nn

__all__ = ["conv3x3"]


def conv3x3(channels: int, out: int, stride: int = 1, orthogonal: bool = True) -> nn.Conv2d:
    """A 3x3 convolution; ``orthogonal``: initialised as DrQ's are (orthogonal weights with ReLU's gain, zero bias),
    else PyTorch's default. The RL encoders use DrQ's: PyTorch's default draws weights with a sixth of the variance
    that He's initialisation keeps a ReLU stack's signal with, and on the grasp bin's pictures (mostly floor) the
    critic's network, taught "would closing here hold an object" directly (``benchmarks/grasp_probe.py``), reached
    AUC 0.74 in 2,000 updates with DrQ's against 0.57 with PyTorch's (both 0.88-0.89 at 6,000). Behaviour cloning
    keeps PyTorch's, the one its results were measured with."""
    conv = nn.Conv2d(channels, out, 3, stride=stride, padding=1)
    if orthogonal:
        nn.init.orthogonal_(conv.weight, nn.init.calculate_gain("relu"))
        nn.init.zeros_(conv.bias)
    return conv
