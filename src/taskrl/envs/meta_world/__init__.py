"""Meta-World v3 task sets (MT1, MT10, MT50, custom lists) as batched multi-task environments.

Needs the ``metaworld`` extra (``pip install 'taskrl[metaworld]'``, Meta-World 3.1.1 with MuJoCo
3.3.0); everything except `MetaWorldMultiTaskEnv` works without it.

- `METAWORLD_DESCRIPTIONS`: one human-written sentence for each of the 50 tasks, keyed by
  the version-free name (``reach``, ``pick-place``) in Meta-World's MT50 order; the metadata
  that language conditioning (CARE) embeds.
- `metaworld_task_set`: the [`TaskSet`][taskrl.tasks.TaskSet] of a benchmark.
- `MetaWorldMultiTaskEnv`: one vector slot per task (or ``envs_per_task``), observations
  ``{"observation": 39-d float32, "task": int64 index}``, ``info["is_success"]`` from Meta-World's
  ``info["success"]``, goal positions drawn afresh at every reset. It is a
  [`GymnasiumVectorEnv`][taskrl.envs.gymnasium_adapter.GymnasiumVectorEnv], so numpy becomes torch, autoreset
  and final observations are handled in that one place.
- the families ``mt1``, ``mt10`` and ``mt50`` (section ``metaworld``).

Meta-World's evaluation protocol (per task, episodes over distinct goal positions, success if
reached at any step) is [`taskrl.training.per_task.evaluate_per_task`][taskrl.training.per_task.evaluate_per_task].

Meta-World settings chosen (see ``docs/multitask.md``): ``use_one_hot`` always passed explicitly;
``task_select="random"`` so every reset picks one of the task's 50 pre-drawn goal positions
(``"pseudorandom"`` would keep one goal until ``sample_tasks()`` is called); Meta-World's reward
version ``"v2"`` (its default); horizon 500 (Meta-World's ``max_path_length``), configurable.
"""

from taskrl.envs.meta_world.catalogue import (
    METAWORLD_DESCRIPTIONS,
    METAWORLD_HORIZON,
    METAWORLD_NUM_GOALS,
    METAWORLD_PARAPHRASES,
    MT10_TASKS,
    MT50_TASKS,
    hide_goal,
    metaworld_id,
    metaworld_spec,
    metaworld_task_set,
    version_free,
)
from taskrl.envs.meta_world.env import MetaWorldMultiTaskEnv
from taskrl.envs.meta_world.family import FAMILIES, MetaWorldSettings, metaworld_expert

__all__ = [
    "FAMILIES",
    "METAWORLD_DESCRIPTIONS",
    "METAWORLD_HORIZON",
    "METAWORLD_NUM_GOALS",
    "METAWORLD_PARAPHRASES",
    "MT10_TASKS",
    "MT50_TASKS",
    "MetaWorldMultiTaskEnv",
    "MetaWorldSettings",
    "hide_goal",
    "metaworld_expert",
    "metaworld_id",
    "metaworld_spec",
    "metaworld_task_set",
    "version_free",
]
