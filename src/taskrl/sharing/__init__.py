"""Data sharing between tasks: experience collected for one task, relabelled with another task's reward.

- `settings` — `SharingConfig`, the ``data_sharing`` section of a run (``--sharing``).
- `strategies` — `TaskSharing`, the sampler that draws each task's rows from its own and
  other tasks' data by a strategy and scores them with the task's reward function.
- `strategy`, `registry`, `builtin` — what a strategy declares, the strategies by name
  (``none``, ``all``, ``random``, ``success``, ``hipi``, ``conservative``, ``zero-reward``), the built-in ones.
- `datasets` — per-task offline datasets of a chosen quality (expert, medium, random).

See ``docs/sharing.md`` for the equations and the results.
"""

from taskrl.lazy_exports import lazy_exports

_EXPORTS = {
    "collect_task_datasets": "taskrl.sharing.datasets",
    "SHARING_STRATEGIES": "taskrl.sharing.registry",
    "register_sharing_strategy": "taskrl.sharing.registry",
    "SharingConfig": "taskrl.sharing.settings",
    "EpisodeScores": "taskrl.sharing.strategies",
    "TaskSharing": "taskrl.sharing.strategies",
    "SharingStrategy": "taskrl.sharing.strategy",
}
__getattr__ = lazy_exports(__name__, _EXPORTS)

__all__ = [*_EXPORTS]
