"""Networks told which task to do: ``f(x, context, task)`` for every agent's actor, critic or policy.

One module, `ConditionedMLP`, covers the architectures a run can choose (``architecture``):

    none     y = MLP([x, e])                                      single-task (no context)
    concat   y = MLP([x, e, c])                                   the union MDP: context appended
    film     y = FiLMMLP([x, e]; c)                               every hidden layer FiLM-modulated by c
    care     y = MLP([CARE(x, c), e]) = MLP([sum_j w_j(c) f_j(x), c, e])     k encoders mixed by attention

``x`` is the (normalised) state, ``c`` the task context from a
[`TaskEncoder`][taskrl.conditioning.task_encoders.TaskEncoder], and ``e`` an optional extra input that joins
after the conditioning (a critic's action: CARE encodes the state, as in the paper, and the action
enters the trunk). With ``num_heads > 1`` the last layer has one head per task and row ``b`` reads
head ``task[b]`` (multi-head SAC); the trunk stays shared. All tasks go through one forward pass.

`ConditioningConfig` is the section of a run's configuration that picks these, and
`make_conditioning` builds the shared task encoder from it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import torch
from torch import nn

from taskrl.conditioning.care import CAREEncoder
from taskrl.conditioning.film import FiLMMLP
from taskrl.conditioning.settings import ARCHITECTURES, ConditioningConfig
from taskrl.conditioning.task_encoders import TaskEncoder, make_task_encoder
from taskrl.nets import mlp

__all__ = ["ARCHITECTURES", "ConditionedMLP", "ConditioningConfig", "TaskConditioning", "make_conditioning", "network_for"]


class ConditionedMLP(nn.Module):
    """``forward(x, context=None, task=None, extra=None) -> [B, out_dim]``.

    Args:
        in_dim: width of the state ``x``.
        out_dim: width of the output (per head).
        hidden_sizes: widths of the hidden layers of the trunk.
        context_dim: width of the context; 0 means no conditioning (a plain MLP).
        architecture: ``concat``, ``film`` or ``care`` (see the module docstring).
        extra_dim: width of an extra input joining after the conditioning (a critic's action).
        num_heads: output heads (one per task for multi-head networks); ``task`` picks the head.
        care_encoders: CARE's k.
        care_encoder_dim: width of each CARE encoding.
    """

    def __init__(
        self,
        in_dim: int,
        out_dim: int,
        hidden_sizes: Sequence[int],
        context_dim: int = 0,
        architecture: str = "concat",
        extra_dim: int = 0,
        num_heads: int = 1,
        care_encoders: int = 4,
        care_encoder_dim: int = 64,
    ) -> None:
        super().__init__()
        if architecture not in ARCHITECTURES:
            raise ValueError(f"architecture: unknown {architecture!r}; allowed: {', '.join(ARCHITECTURES)}")
        if num_heads < 1:
            raise ValueError(f"num_heads: must be >= 1 (got {num_heads})")
        self.out_dim, self.num_heads = int(out_dim), int(num_heads)
        self.architecture = architecture if context_dim > 0 else "none"
        hidden_sizes = tuple(hidden_sizes)
        width = out_dim * num_heads
        if self.architecture == "none":
            self.body = mlp(in_dim + extra_dim, hidden_sizes, width)
        elif self.architecture == "concat":
            self.body = mlp(in_dim + extra_dim + context_dim, hidden_sizes, width)
        elif self.architecture == "film":
            self.film = FiLMMLP(in_dim + extra_dim, hidden_sizes, width, context_dim)
        else:  # care: the first hidden layer's width is each encoder's hidden width
            self.care = CAREEncoder(in_dim, context_dim, care_encoders, hidden_sizes[:1], care_encoder_dim)
            self.body = mlp(self.care.out_dim + extra_dim, hidden_sizes[1:] or hidden_sizes, width)

    def forward(
        self,
        x: torch.Tensor,
        context: torch.Tensor | None = None,
        task: torch.Tensor | None = None,
        extra: torch.Tensor | None = None,
    ) -> torch.Tensor:
        arch = self.architecture
        if arch != "none" and context is None:
            raise ValueError(f"a {arch!r}-conditioned network needs the task context")
        if arch == "none":
            y = self.body(x if extra is None else torch.cat([x, extra], dim=-1))
        elif arch == "concat":
            parts = [x, context] if extra is None else [x, extra, context]
            y = self.body(torch.cat(parts, dim=-1))
        elif arch == "film":
            y = self.film(x if extra is None else torch.cat([x, extra], dim=-1), context)
        else:
            z = self.care(x, context)
            y = self.body(z if extra is None else torch.cat([z, extra], dim=-1))
        if self.num_heads == 1:
            return y
        if task is None:
            raise ValueError("a multi-head network needs the task index of every row")
        rows = torch.arange(y.shape[0], device=y.device)
        return y.view(y.shape[0], self.num_heads, self.out_dim)[rows, task.long().view(-1)]


@dataclasses.dataclass
class TaskConditioning:
    """What an agent needs to condition its networks: the shared task encoder and the architecture.

    Attributes:
        encoder: maps ``obs[task_key]`` to the context (shared by every network of the agent).
        config: the architecture choices.
        task_key: the observation key holding the task index.
    """

    encoder: TaskEncoder
    config: ConditioningConfig
    task_key: str = "task"

    @property
    def num_tasks(self) -> int:
        return self.encoder.num_tasks

    def task_inputs(self, obs: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """``(context [B, C], task index [B])`` of a batch of observations."""
        task = obs[self.task_key].long().view(-1)
        return self.encoder(task), task

    def network(self, in_dim: int, out_dim: int, hidden_sizes: Sequence[int], extra_dim: int = 0) -> ConditionedMLP:
        """A `ConditionedMLP` with this conditioning (one head per task if ``multi_head``)."""
        c = self.config
        return ConditionedMLP(
            in_dim,
            out_dim,
            hidden_sizes,
            self.encoder.context_dim,
            c.architecture,
            extra_dim,
            self.num_tasks if c.multi_head else 1,
            c.care_encoders,
            c.care_encoder_dim,
        )


def make_conditioning(
    config: ConditioningConfig, num_tasks: int, descriptions: Sequence[str] | None = None, task_key: str = "task"
) -> TaskConditioning:
    """The `TaskConditioning` a config names, for ``num_tasks`` tasks described by ``descriptions``."""
    encoder = make_task_encoder(
        config.task_encoder,
        num_tasks,
        dim=config.embedding_dim,
        descriptions=descriptions,
        projection_dim=config.projection_dim or None,
    )
    return TaskConditioning(encoder, config, task_key)


def network_for(
    in_dim: int, out_dim: int, hidden_sizes: Sequence[int], conditioning: TaskConditioning | None, extra_dim: int = 0
) -> ConditionedMLP:
    """``conditioning.network(...)`` for a multi-task agent, an unconditioned network otherwise."""
    if conditioning is None:
        return ConditionedMLP(in_dim, out_dim, hidden_sizes, extra_dim=extra_dim)
    return conditioning.network(in_dim, out_dim, hidden_sizes, extra_dim)
