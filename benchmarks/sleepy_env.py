"""A robot stand-in for the scaling benchmark: PointReach whose steps take a fixed wall time.

Real robots collect in real time (a 50 Hz arm takes 20 ms a step whatever the CPU), so collection
scales with the number of robots, not with cores. ``bench/SleepyPointReach-v0`` is taskrl's
PointReach with ``time.sleep(SLEEPY_STEP_SECONDS)`` (default 0.02) after every step, in every process
except the one whose id is ``SLEEPY_DRIVER_PID`` (the trainer's, whose evaluation copies then run at
full speed). Import it with ``--env-module sleepy_env`` (``benchmarks/`` on ``PYTHONPATH``).
"""

from __future__ import annotations

import os
import time

import gymnasium as gym

import taskrl  # noqa: F401  (registers taskrl/PointReach-v0)


class SleepyStep(gym.Wrapper):
    """Each ``step`` takes at least ``seconds`` of wall time."""

    def __init__(self, env: gym.Env, seconds: float) -> None:
        super().__init__(env)
        self.seconds = seconds

    def step(self, action):
        started = time.perf_counter()
        out = self.env.step(action)
        left = self.seconds - (time.perf_counter() - started)
        if left > 0:
            time.sleep(left)
        return out

    def compute_reward(self, achieved_goal, desired_goal, info):
        return self.env.unwrapped.compute_reward(achieved_goal, desired_goal, info)


def make_sleepy(**kwargs) -> gym.Env:
    env = gym.make("taskrl/PointReach-v0", **kwargs)
    in_driver = os.environ.get("SLEEPY_DRIVER_PID") == str(os.getpid())
    return env if in_driver else SleepyStep(env, float(os.environ.get("SLEEPY_STEP_SECONDS", "0.02")))


if "bench/SleepyPointReach-v0" not in gym.registry:
    gym.register("bench/SleepyPointReach-v0", entry_point=make_sleepy, max_episode_steps=50)
