"""Grasp success of uniformly random actions, per object set: the floor a learned grasp policy must beat.

.venv/bin/python benchmarks/grasp_random.py   # about 10,000 attempts per object set, seed 0
"""

from __future__ import annotations

import torch

from taskrl.envs.grasp import Grasp, GraspSettings


def random_success(
    objects: str, attempts: int = 10_000, bins: int = 1024, seed: int = 0, tolerance: float = GraspSettings.tolerance
) -> tuple[int, float]:
    """(attempts ended, fraction that held an object) for actions uniform in the box; ``tolerance``: the env's."""
    env = Grasp(GraspSettings(objects=objects, tolerance=tolerance), num_envs=bins, seed=seed)
    env.reset(seed=seed)
    generator = torch.Generator().manual_seed(seed)
    ended = held = 0
    while ended < attempts:
        _, _, terminated, truncated, info = env.step(torch.rand(bins, 4, generator=generator) * 2 - 1)
        done = terminated | truncated
        ended += int(done.sum())
        held += int((info["is_success"] & done).sum())
    return ended, held / ended


if __name__ == "__main__":
    torch.set_num_threads(1)
    for objects in ("train", "held_out"):
        ended, success = random_success(objects)
        print(f"{objects}: {ended} attempts, success {success:.3f}")
