"""Task conditioning: encoders from a task index to a context, and networks that use the context.

- `task_encoders` — one-hot, learned embedding, language (frozen sentence embeddings).
- `language` — all-MiniLM-L6-v2 embeddings of task descriptions, offline, cached on disk
  (needs the ``language`` extra only when the cache misses).
- `film` — FiLM layers and an MLP whose hidden layers are modulated by the context.
- `care` — CARE: k state encoders mixed by attention on the context.

See ``docs/conditioning.md`` for the equations.
"""

from taskrl.conditioning.care import CAREEncoder, ParallelLinear
from taskrl.conditioning.film import FiLM, FiLMMLP
from taskrl.conditioning.language import EMBEDDING_DIM, MODEL_NAME, sentence_embeddings
from taskrl.conditioning.task_encoders import (
    TASK_ENCODERS,
    LanguageTaskEncoder,
    LearnedTaskEmbedding,
    OneHotTaskEncoder,
    TaskEncoder,
    make_task_encoder,
)

__all__ = [
    "CAREEncoder",
    "EMBEDDING_DIM",
    "FiLM",
    "FiLMMLP",
    "LanguageTaskEncoder",
    "LearnedTaskEmbedding",
    "MODEL_NAME",
    "OneHotTaskEncoder",
    "ParallelLinear",
    "TASK_ENCODERS",
    "TaskEncoder",
    "make_task_encoder",
    "sentence_embeddings",
]
