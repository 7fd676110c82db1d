"""Types shared by every layer: an observation batch is a dict of tensors with a leading batch dimension."""

from __future__ import annotations

import torch

#: A batch of observations by key (``observation``, ``achieved_goal``, ``desired_goal``, ``task``).
Obs = dict[str, torch.Tensor]
