"""The gymnasium ids of taskrl's native environments, registered by ``import taskrl``.

Entry points are strings, so registering imports nothing but gymnasium; ``gymnasium.make`` then
imports the environment's module. Idempotent.
"""

from __future__ import annotations

import gymnasium as gym

__all__ = ["NATIVE_IDS", "register_gymnasium_envs"]

#: id -> (entry point, registered time limit or None)
NATIVE_IDS: dict[str, tuple[str, int | None]] = {
    "taskrl/BitFlip-v0": ("taskrl.envs.gymnasium_env:BitFlipGymEnv", None),
    "taskrl/PointReach-v0": ("taskrl.envs.gymnasium_env:PointReachGymEnv", 50),
    "taskrl/MultiTaskPointReach-v0": ("taskrl.envs.multitask_point:MultiTaskPointReachGymEnv", 50),
    "taskrl/GridTasks-v0": ("taskrl.envs.grid_tasks:GridTasksGymEnv", 30),
    "taskrl/PointTasks-v0": ("taskrl.envs.point_tasks:PointTasksGymEnv", 40),
    "taskrl/Grasp-v0": ("taskrl.envs.grasp:GraspGymEnv", None),
    "taskrl/KukaGrasp-v0": ("taskrl.envs.kuka_grasp:KukaGraspEnv", None),
    "taskrl/PixelReach-v0": ("taskrl.envs.pixel_reach:PixelReachGymEnv", 50),
    "taskrl/PixelPush-v0": ("taskrl.envs.pixel_push:PixelPushGymEnv", 50),
    "taskrl/Tabletop-v0": ("taskrl.envs.tabletop:TabletopGymEnv", 50),
}


def register_gymnasium_envs() -> None:
    """Register the native environments under the ``taskrl/`` namespace (idempotent)."""
    for env_id, (entry_point, steps) in NATIVE_IDS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, max_episode_steps=steps)
