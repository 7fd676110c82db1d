"""Environments: native batched torch environments, the gymnasium adapter, and registrations."""

from taskrl.envs.base import BatchedEnv, GoalEnvMixin, is_goal_env
from taskrl.envs.bitflip import BitFlip
from taskrl.envs.gymnasium_adapter import GymnasiumGoalEnv
from taskrl.envs.gymnasium_env import BitFlipGymEnv, PointReachGymEnv, register_gymnasium_envs
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
    "register_gymnasium_envs",
]
