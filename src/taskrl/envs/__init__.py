"""Environments: native batched torch environments, the gymnasium adapter, and the env families.

``taskrl.envs.registry`` lists the families a run can name (``--env``); each is declared next to its
environments (``bitflip.FAMILY``, ``meta_world.FAMILIES``, ...).
"""

from taskrl.lazy_exports import lazy_exports
from taskrl.registration import register_gymnasium_envs

register_gymnasium_envs()

_EXPORTS = {
    "BatchedEnv": "taskrl.envs.base",
    "GoalEnvMixin": "taskrl.envs.base",
    "is_goal_env": "taskrl.envs.base",
    "BitFlip": "taskrl.envs.bitflip",
    "GymnasiumGoalEnv": "taskrl.envs.gymnasium_adapter",
    "GymnasiumVectorEnv": "taskrl.envs.gymnasium_adapter",
    "BitFlipGymEnv": "taskrl.envs.gymnasium_env",
    "PointReachGymEnv": "taskrl.envs.gymnasium_env",
    "MetaWorldMultiTaskEnv": "taskrl.envs.meta_world",
    "metaworld_task_set": "taskrl.envs.meta_world",
    "MultiTaskPointReach": "taskrl.envs.multitask_point",
    "MultiTaskPointReachGymEnv": "taskrl.envs.multitask_point",
    "PointReach": "taskrl.envs.point_reach",
    "EnvFamily": "taskrl.envs.spec",
    "EnvRequest": "taskrl.envs.spec",
    "env_kind": "taskrl.envs.spec",
    "TaskSetEnv": "taskrl.envs.task_sets",
}
__getattr__ = lazy_exports(__name__, _EXPORTS)

__all__ = ["register_gymnasium_envs", *_EXPORTS]
