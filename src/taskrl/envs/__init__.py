"""Environments: native batched torch environments, the gymnasium adapter, and the env families.

``taskrl.envs.registry`` lists the families a run can name (``--env``); each is declared next to its
environments (``bitflip.FAMILY``, ``meta_world.FAMILIES``, ...).
"""

from taskrl.envs.base import BatchedEnv, GoalEnvMixin, is_goal_env
from taskrl.envs.bitflip import BitFlip
from taskrl.envs.gymnasium_adapter import GymnasiumGoalEnv, GymnasiumVectorEnv
from taskrl.envs.gymnasium_env import BitFlipGymEnv, PointReachGymEnv
from taskrl.envs.meta_world import MetaWorldMultiTaskEnv, metaworld_task_set
from taskrl.envs.multitask_point import MultiTaskPointReach, MultiTaskPointReachGymEnv
from taskrl.envs.point_reach import PointReach
from taskrl.envs.spec import EnvFamily, EnvRequest, env_kind
from taskrl.envs.task_sets import TaskSetEnv
from taskrl.registration import register_gymnasium_envs

register_gymnasium_envs()

__all__ = [
    "BatchedEnv",
    "BitFlip",
    "BitFlipGymEnv",
    "EnvFamily",
    "EnvRequest",
    "GoalEnvMixin",
    "GymnasiumGoalEnv",
    "GymnasiumVectorEnv",
    "MetaWorldMultiTaskEnv",
    "MultiTaskPointReach",
    "MultiTaskPointReachGymEnv",
    "PointReach",
    "PointReachGymEnv",
    "TaskSetEnv",
    "env_kind",
    "is_goal_env",
    "metaworld_task_set",
    "register_gymnasium_envs",
]
