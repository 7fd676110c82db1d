"""Task encoders: a task index ``[B]`` in, a context vector ``[B, C]`` out.

Every encoder is an ``nn.Module`` with ``forward(task_index) -> context`` and the attribute
``context_dim`` (= C), so the networks that consume the context (a plain MLP on
``[state, context]``, [`FiLMMLP`][taskrl.conditioning.film.FiLMMLP],
[`CAREEncoder`][taskrl.conditioning.care.CAREEncoder]) never need to know which encoder made it.

    one-hot            c = e_i                      (exact, no parameters)
    learned embedding  c = E[i],  E in R^{T x d}    (trained with the agent)
    language           c = L[i]          or  c = W L[i] + b
                       L in R^{T x 384}: frozen sentence embeddings of the task descriptions,
                       optional trainable linear projection W, b; optional Gaussian noise on L[i]
                       while training (BC-Z uses std 0.1)
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
from torch import nn

from taskrl.conditioning.settings import TASK_ENCODERS

__all__ = [
    "TASK_ENCODERS",
    "LanguageTaskEncoder",
    "LearnedTaskEmbedding",
    "OneHotTaskEncoder",
    "TaskEncoder",
    "make_task_encoder",
]


def _as_index(task_index: torch.Tensor) -> torch.Tensor:
    """``[B]`` or ``[B, 1]`` integer tensor -> ``[B]`` long tensor."""
    if task_index.dim() == 2 and task_index.shape[1] == 1:
        task_index = task_index[:, 0]
    if task_index.dim() != 1:
        raise ValueError(f"task_index: expected shape [B] or [B, 1] (got {tuple(task_index.shape)})")
    if task_index.dtype.is_floating_point or task_index.dtype == torch.bool:
        raise TypeError(f"task_index: expected an integer tensor (got {task_index.dtype})")
    return task_index.long()


class TaskEncoder(nn.Module):
    """Base class: ``forward(task_index LongTensor [B]) -> context [B, context_dim]``.

    Attributes:
        num_tasks: number of tasks T (valid indices are ``0 .. T-1``).
        context_dim: width C of the context.
    """

    num_tasks: int
    context_dim: int

    def __init__(self, num_tasks: int, context_dim: int) -> None:
        super().__init__()
        if num_tasks < 1:
            raise ValueError(f"num_tasks: must be >= 1 (got {num_tasks})")
        if context_dim < 1:
            raise ValueError(f"context_dim: must be >= 1 (got {context_dim})")
        self.num_tasks, self.context_dim = int(num_tasks), int(context_dim)

    def encode(self, task_index: torch.Tensor) -> torch.Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def forward(self, task_index: torch.Tensor) -> torch.Tensor:
        return self.encode(_as_index(task_index))

    def extra_repr(self) -> str:
        return f"num_tasks={self.num_tasks}, context_dim={self.context_dim}"


class OneHotTaskEncoder(TaskEncoder):
    """``c = e_i``: row i of the T x T identity (exact zeros and ones; no parameters).

    The identity is a non-persistent buffer, so the context follows the module's device and dtype
    and checkpoints carry nothing for it.
    """

    def __init__(self, num_tasks: int) -> None:
        super().__init__(num_tasks, num_tasks)
        self.register_buffer("eye", torch.eye(num_tasks), persistent=False)

    def encode(self, task_index: torch.Tensor) -> torch.Tensor:
        return self.eye[task_index]


class LearnedTaskEmbedding(TaskEncoder):
    """``c = E[i]``: a trainable table ``E`` of shape ``[num_tasks, dim]`` (``nn.Embedding``, N(0, 1) init)."""

    def __init__(self, num_tasks: int, dim: int) -> None:
        super().__init__(num_tasks, dim)
        self.embedding = nn.Embedding(num_tasks, dim)

    def encode(self, task_index: torch.Tensor) -> torch.Tensor:
        return self.embedding(task_index)


class LanguageTaskEncoder(TaskEncoder):
    """``c = L[i]`` or ``c = W L[i] + b``: a frozen table of sentence embeddings, one row per task.

    Args:
        embeddings: ``[T, D]`` precomputed embeddings (``D = 384`` for all-MiniLM-L6-v2; see
            [`taskrl.conditioning.language.sentence_embeddings`][taskrl.conditioning.language.sentence_embeddings]). Stored as a buffer: never
            trained, saved in ``state_dict`` so a checkpoint is self-contained.
        trainable_projection_dim: if given, a trainable ``nn.Linear(D, P)`` maps the embedding to the
            context (``context_dim = P``); otherwise ``context_dim = D``.
        noise_std: standard deviation of Gaussian noise added to ``L[i]`` in training mode only
            (BC-Z regularises its language embedding with 0.1); 0 disables.
    """

    def __init__(self, embeddings: torch.Tensor, trainable_projection_dim: int | None = None, noise_std: float = 0.0) -> None:
        embeddings = torch.as_tensor(embeddings)
        if embeddings.dim() != 2:
            raise ValueError(f"embeddings: expected shape [num_tasks, dim] (got {tuple(embeddings.shape)})")
        if noise_std < 0:
            raise ValueError(f"noise_std: must be >= 0 (got {noise_std})")
        num_tasks, dim = embeddings.shape
        super().__init__(num_tasks, trainable_projection_dim or dim)
        self.embedding_dim = int(dim)
        self.noise_std = float(noise_std)
        self.register_buffer("table", embeddings.detach().float().clone())
        self.projection = nn.Linear(dim, trainable_projection_dim) if trainable_projection_dim else None

    @classmethod
    def from_descriptions(
        cls,
        descriptions: Sequence[str],
        trainable_projection_dim: int | None = None,
        noise_std: float = 0.0,
        cache_dir: str | Path | None = None,
    ) -> LanguageTaskEncoder:
        """Embeds the task descriptions (cached on disk, see ``sentence_embeddings``) and builds the encoder."""
        from taskrl.conditioning.language import sentence_embeddings

        return cls(sentence_embeddings(list(descriptions), cache_dir=cache_dir), trainable_projection_dim, noise_std)

    def encode(self, task_index: torch.Tensor) -> torch.Tensor:
        e = self.table[task_index]
        if self.training and self.noise_std > 0:
            e = e + self.noise_std * torch.randn_like(e)
        return self.projection(e) if self.projection is not None else e


def make_task_encoder(
    kind: str,
    num_tasks: int,
    *,
    dim: int = 32,
    descriptions: Sequence[str] | None = None,
    embeddings: torch.Tensor | None = None,
    projection_dim: int | None = None,
    noise_std: float = 0.0,
    cache_dir: str | Path | None = None,
) -> TaskEncoder:
    """Builds the task encoder a config names.

    Args:
        kind: ``"onehot"``, ``"embedding"`` (learned, width ``dim``) or ``"language"``.
        num_tasks: number of tasks T.
        dim: width of the learned embedding.
        descriptions: language only: one sentence per task (embedded and cached), unless
            ``embeddings`` is given.
        embeddings: language only: a precomputed ``[T, D]`` table.
        projection_dim: language only: width of the optional trainable projection.
        noise_std: language only: training-time noise on the embedding.
        cache_dir: language only: where embeddings are cached.
    """
    if kind == "onehot":
        return OneHotTaskEncoder(num_tasks)
    if kind == "embedding":
        return LearnedTaskEmbedding(num_tasks, dim)
    if kind == "language":
        if embeddings is None:
            if descriptions is None:
                raise ValueError("task encoder 'language': needs `descriptions` (one sentence per task) or `embeddings`")
            if len(descriptions) != num_tasks:
                raise ValueError(f"descriptions: expected {num_tasks} (one per task), got {len(descriptions)}")
            return LanguageTaskEncoder.from_descriptions(descriptions, projection_dim, noise_std, cache_dir)
        if embeddings.shape[0] != num_tasks:
            raise ValueError(f"embeddings: expected {num_tasks} rows (one per task), got {embeddings.shape[0]}")
        return LanguageTaskEncoder(embeddings, projection_dim, noise_std)
    raise ValueError(f"task encoder: unknown kind {kind!r}; allowed: {', '.join(TASK_ENCODERS)}")
