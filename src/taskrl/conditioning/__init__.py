"""Task conditioning: encoders from a task index to a context, and networks that use the context.

- `task_encoders` — one-hot, learned embedding, language (frozen sentence embeddings).
- `language` — all-MiniLM-L6-v2 embeddings of task descriptions, offline, cached on disk
  (needs the ``language`` extra only when the cache misses).
- `film` — FiLM layers and an MLP whose hidden layers are modulated by the context.
- `care` — CARE: k state encoders mixed by attention on the context.

See ``docs/conditioning.md`` for the equations.
"""

from taskrl.lazy_exports import lazy_exports

_EXPORTS = {
    "CAREEncoder": "taskrl.conditioning.care",
    "ParallelLinear": "taskrl.conditioning.care",
    "FiLM": "taskrl.conditioning.film",
    "FiLMMLP": "taskrl.conditioning.film",
    "EMBEDDING_DIM": "taskrl.conditioning.language",
    "MODEL_NAME": "taskrl.conditioning.language",
    "sentence_embeddings": "taskrl.conditioning.language",
    "TASK_ENCODERS": "taskrl.conditioning.settings",
    "LanguageTaskEncoder": "taskrl.conditioning.task_encoders",
    "LearnedTaskEmbedding": "taskrl.conditioning.task_encoders",
    "OneHotTaskEncoder": "taskrl.conditioning.task_encoders",
    "TaskEncoder": "taskrl.conditioning.task_encoders",
    "make_task_encoder": "taskrl.conditioning.task_encoders",
}
__getattr__ = lazy_exports(__name__, _EXPORTS)

__all__ = [*_EXPORTS]
