"""Data sharing between tasks: experience collected for one task, relabelled with another task's reward.

- :mod:`settings` — :class:`SharingConfig`, the ``data_sharing`` section of a run (``--sharing``).
- :mod:`strategies` — :class:`TaskSharing`, the sampler that draws each task's rows from its own and
  other tasks' data by a strategy (``none``, ``all``, ``random``, ``success``, ``hipi``,
  ``conservative``, ``zero-reward``) and scores them with the task's reward function.
- :mod:`datasets` — per-task offline datasets of a chosen quality (expert, medium, random).

See ``docs/sharing.md`` for the equations and the results.
"""

from taskrl.sharing.datasets import collect_task_datasets
from taskrl.sharing.settings import SHARING_STRATEGIES, SharingConfig
from taskrl.sharing.strategies import EpisodeScores, TaskSharing

__all__ = ["EpisodeScores", "SHARING_STRATEGIES", "SharingConfig", "TaskSharing", "collect_task_datasets"]
