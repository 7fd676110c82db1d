"""Environments: native batched torch environments and their gymnasium registrations."""

from taskrl.envs.base import BatchedEnv, GoalEnvMixin, is_goal_env
from taskrl.envs.bitflip import BitFlip
from taskrl.envs.gymnasium_env import BitFlipGymEnv, register_gymnasium_envs

register_gymnasium_envs()

__all__ = ["BatchedEnv", "GoalEnvMixin", "is_goal_env", "BitFlip", "BitFlipGymEnv", "register_gymnasium_envs"]
