"""Per-task offline datasets of a chosen quality, made by the project (CDS's mixed-quality datasets).

``expert``: the env's scripted expert (``env.expert_action``); ``medium``: the expert with each action
replaced by a uniformly random one with probability 1/2; ``random``: uniformly random actions. Every
task gets the same number of transitions whatever its quality, so better data is more episodes.
"""

from __future__ import annotations

from collections.abc import Mapping

import gymnasium as gym
import torch

from taskrl.replay.episodes import EpisodeRecorder, Episodes

__all__ = ["RANDOM_SHARE", "collect_task_datasets", "random_actions"]

#: the probability of a uniformly random action in place of the expert's, by dataset quality
RANDOM_SHARE = {"expert": 0.0, "medium": 0.5, "random": 1.0}


def random_actions(space: gym.spaces.Space, n: int, generator: torch.Generator, device: torch.device) -> torch.Tensor:
    """``n`` uniformly random actions of a ``Discrete`` or ``Box`` space."""
    if isinstance(space, gym.spaces.Discrete):
        return torch.randint(int(space.n), (n,), generator=generator, device=device)
    low = torch.as_tensor(space.low, device=device)
    high = torch.as_tensor(space.high, device=device)
    return low + (high - low) * torch.rand((n, *space.shape), generator=generator, device=device)


def collect_task_datasets(env, qualities: Mapping[str, str], steps_per_task: int, seed: int) -> Episodes:
    """Whole episodes, ``steps_per_task`` transitions of every task (the running ones cut at the end).

    Args:
        env: a multi-task env with fixed tasks per copy (``slot_tasks``, copy ``i`` on task ``i % T``),
            ``expert_action(obs)`` and ``task_set``; its copies are stepped together.
        qualities: ``{task name: expert | medium | random}`` for every task.
        steps_per_task: transitions of each task (rounded up to a multiple of the copies per task).
        seed: seed of the env and of the random actions.
    """
    names = env.task_set.names
    random_share = torch.tensor([RANDOM_SHARE[qualities[n]] for n in names], device=env.device)[env.slot_tasks.long()]
    per_task = env.num_envs // len(names)
    generator = torch.Generator(device=env.device)
    generator.manual_seed(seed)
    recorder = EpisodeRecorder(env.single_observation_space, env.single_action_space, env.num_envs, env.device, env.horizon)
    obs = env.reset(seed=seed)
    recorder.start(obs)
    for _ in range(-(-steps_per_task // per_task)):
        expert = env.expert_action(obs)
        noise = random_actions(env.single_action_space, env.num_envs, generator, env.device).to(expert.dtype)
        pick = torch.rand(env.num_envs, generator=generator, device=env.device) < random_share
        action = torch.where(pick.view(-1, *[1] * (expert.dim() - 1)), noise, expert)
        next_obs, reward, terminated, truncated, info = env.step(action)
        recorder.add(action, reward, terminated, truncated, info["final_obs"], next_obs)
        obs = next_obs
    recorder.cut_running()
    return recorder.drain()
