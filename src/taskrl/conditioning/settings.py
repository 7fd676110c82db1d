"""How a multi-task run tells its networks the task: `ConditioningConfig` (the ``conditioning`` section), without
the networks (a config reads it without importing torch)."""

from __future__ import annotations

import dataclasses
from typing import Literal

from taskrl.errors import one_of, require

__all__ = ["ARCHITECTURES", "TASK_ENCODERS", "ConditioningConfig"]

TASK_ENCODERS = ("onehot", "embedding", "language")
ARCHITECTURES = ("concat", "film", "care")


@dataclasses.dataclass
class ConditioningConfig:
    """How a multi-task run tells its networks the task (ignored by single-task runs).

    Attributes:
        task_encoder: the task context: ``onehot`` (exact, T-d), ``embedding`` (learned,
            ``embedding_dim``-d) or ``language`` (frozen all-MiniLM-L6-v2 embedding of the task's
            one-sentence description, 384-d, cached on disk; needs the ``language`` extra).
        architecture: how networks use the context: ``concat`` (appended to the state), ``film``
            (scale and shift of every hidden layer) or ``care`` (k state encoders mixed by
            attention weights computed from the context, then concatenated with it).
        multi_head: one output head per task on a shared trunk (actor and critics).
        embedding_dim: width of the learned task embedding.
        projection_dim: language only: width of a trainable linear projection of the sentence
            embedding (0 = use the 384-d embedding as is).
        care_encoders: CARE's number of state encoders k.
        care_encoder_dim: width of each CARE encoding.
    """

    task_encoder: Literal["onehot", "embedding", "language"] = "onehot"
    architecture: Literal["concat", "film", "care"] = "concat"
    multi_head: bool = False
    embedding_dim: int = 32
    projection_dim: int = 0
    care_encoders: int = 4
    care_encoder_dim: int = 64

    def validate(self) -> None:
        """Raise `ConfigError` naming the first bad setting."""
        one_of(self.task_encoder, TASK_ENCODERS, "task_encoder", "task encoder")
        one_of(self.architecture, ARCHITECTURES, "architecture", "architecture")
        for name in ("embedding_dim", "care_encoders", "care_encoder_dim"):
            require(getattr(self, name) >= 1, name, f"must be >= 1 (got {getattr(self, name)})")
        require(self.projection_dim >= 0, "projection_dim", f"must be >= 0 (got {self.projection_dim})")
