"""Environments: native batched torch environments, the gymnasium adapter, and registrations."""

from taskrl.envs.base import BatchedEnv, GoalEnvMixin, is_goal_env
from taskrl.envs.bitflip import BitFlip
from taskrl.envs.gymnasium_adapter import GymnasiumGoalEnv, GymnasiumVectorEnv
from taskrl.envs.gymnasium_env import BitFlipGymEnv, PointReachGymEnv, register_gymnasium_envs
from taskrl.envs.metaworld_tasks import MetaWorldMultiTaskEnv, evaluate_per_task, metaworld_task_set
from taskrl.envs.multitask_point import MultiTaskPointReach, MultiTaskPointReachGymEnv
from taskrl.envs.point_reach import PointReach

register_gymnasium_envs()

__all__ = [
    "BatchedEnv",
    "GoalEnvMixin",
    "is_goal_env",
    "BitFlip",
    "BitFlipGymEnv",
    "PointReach",
    "PointReachGymEnv",
    "GymnasiumGoalEnv",
    "GymnasiumVectorEnv",
    "MetaWorldMultiTaskEnv",
    "MultiTaskPointReach",
    "MultiTaskPointReachGymEnv",
    "evaluate_per_task",
    "metaworld_task_set",
    "register_gymnasium_envs",
]
