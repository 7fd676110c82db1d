"""Data sharing between tasks: experience collected for one task, relabelled with another task's reward.

- `settings` — `SharingConfig`, the ``data_sharing`` section of a run (``--sharing``).
- `strategies` — `TaskSharing`, the sampler that draws each task's rows from its own and
  other tasks' data by a strategy and scores them with the task's reward function.
- `strategy`, `registry`, `builtin` — what a strategy declares, the strategies by name
  (``none``, ``all``, ``random``, ``success``, ``hipi``, ``conservative``, ``zero-reward``), the built-in ones.
- `datasets` — per-task offline datasets of a chosen quality (expert, medium, random).

See ``docs/sharing.md`` for the equations and the results.
"""

from taskrl.sharing.datasets import collect_task_datasets
from taskrl.sharing.registry import SHARING_STRATEGIES, register_sharing_strategy
from taskrl.sharing.settings import SharingConfig
from taskrl.sharing.strategies import EpisodeScores, TaskSharing
from taskrl.sharing.strategy import SharingStrategy

__all__ = [
    "EpisodeScores",
    "SHARING_STRATEGIES",
    "SharingConfig",
    "SharingStrategy",
    "TaskSharing",
    "collect_task_datasets",
    "register_sharing_strategy",
]
