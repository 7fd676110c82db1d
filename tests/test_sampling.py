import gymnasium as gym
import numpy as np
import pytest
import torch

from taskrl.envs import MultiTaskPointReach
from taskrl.replay import EpisodeReplay, TaskBalancedSampler


def filled_replay(task_weights, episodes=60, horizon=4, seed=0, capacity=None):
    """A replay whose episodes have tasks drawn with the given (unbalanced) weights and random lengths."""
    g = torch.Generator().manual_seed(seed)
    space = gym.spaces.Dict(
        {"observation": gym.spaces.Box(-1, 1, (1,), np.float32), "task": gym.spaces.Discrete(len(task_weights))}
    )
    replay = EpisodeReplay(
        space, gym.spaces.Box(-1, 1, (1,), np.float32), capacity=capacity or episodes * horizon, horizon=horizon, num_envs=1
    )
    weights = torch.tensor(task_weights, dtype=torch.float)
    tasks = torch.multinomial(weights, episodes, replacement=True, generator=g) if episodes else torch.zeros(0, dtype=torch.long)
    for task in tasks.tolist():
        length = int(torch.randint(1, horizon + 1, (1,), generator=g))
        replay.start({"observation": torch.zeros(1, 1), "task": torch.tensor([task])})
        for t in range(length):
            done = torch.tensor([t == length - 1])
            obs = {"observation": torch.full((1, 1), float(t + 1)), "task": torch.tensor([task])}
            replay.add(torch.zeros(1, 1), torch.zeros(1), torch.zeros(1, dtype=torch.bool), done, obs, obs)
    return replay, tasks


def test_every_task_gets_an_equal_share_whatever_its_share_of_the_data():
    replay, tasks = filled_replay([0.7, 0.2, 0.05, 0.05])
    sampler = TaskBalancedSampler(replay, 4)
    batch = sampler(256, torch.Generator().manual_seed(1))
    assert len(batch) == 256
    assert torch.bincount(batch.obs["task"], minlength=4).tolist() == [64, 64, 64, 64]
    uniform = replay.sample(256, torch.Generator().manual_seed(1))
    assert torch.bincount(uniform.obs["task"], minlength=4)[0] > 120  # what balancing corrects
    # rows are real stored transitions: the step lies inside its episode, next obs = step + 1
    assert (batch.step < replay.length[batch.episode]).all()
    assert torch.equal(batch.next_obs["observation"][:, 0], batch.step.float() + 1)


def test_remainder_goes_to_the_lowest_tasks_and_rows_are_task_major():
    replay, _ = filled_replay([0.25] * 3, seed=2)
    batch = TaskBalancedSampler(replay, 3)(10, torch.Generator().manual_seed(0))
    assert batch.obs["task"].tolist() == [0] * 4 + [1] * 3 + [2] * 3


def test_within_a_task_sampling_is_uniform_over_its_transitions():
    replay, _ = filled_replay([0.5, 0.5], episodes=40, seed=3)
    sampler = TaskBalancedSampler(replay, 2)
    e, s = sampler.indices(40_000, torch.Generator().manual_seed(0))
    horizon = 4
    counts = torch.zeros(replay.episode_slots, horizon)
    counts.index_put_((e, s), torch.ones_like(e, dtype=torch.float), accumulate=True)
    task = replay.first_observations("task")
    for k in (0, 1):
        cells = counts[task == k][torch.arange(horizon) < replay.length[task == k][:, None]]
        expected = 20_000 / cells.numel()
        assert (cells - expected).abs().max() < 6 * expected**0.5  # each transition equally likely


def test_a_task_without_data_borrows_from_all_data_and_errors_name_the_problem():
    replay, _ = filled_replay([1.0, 0.0], episodes=10, seed=4)
    batch = TaskBalancedSampler(replay, 2)(64, torch.Generator().manual_seed(0))
    assert len(batch) == 64 and (batch.obs["task"] == 0).all()
    with pytest.raises(ValueError, match="'task' key"):
        space = gym.spaces.Dict({"observation": gym.spaces.Box(-1, 1, (1,), np.float32)})
        TaskBalancedSampler(EpisodeReplay(space, gym.spaces.Box(-1, 1, (1,)), 40, num_envs=1, horizon=4), 2)
    empty, _ = filled_replay([1.0], episodes=0, capacity=40)
    with pytest.raises(RuntimeError, match="empty replay"):
        TaskBalancedSampler(empty, 1)(8)


def test_balanced_batches_from_a_real_multitask_env():
    env = MultiTaskPointReach(num_envs=8, horizon=5, seed=0)
    replay = EpisodeReplay(env.single_observation_space, env.single_action_space, 400, num_envs=env.num_envs, horizon=env.horizon)
    obs = env.reset(seed=0)
    replay.start(obs)
    for _ in range(20):
        nxt, r, term, trunc, info = env.step(torch.zeros(8, 2))
        replay.add(torch.zeros(8, 2), r, term, trunc, info["final_obs"], nxt)
    batch = TaskBalancedSampler(replay, 5)(100, torch.Generator().manual_seed(0))
    assert torch.bincount(batch.obs["task"], minlength=5).tolist() == [20] * 5
    assert torch.equal(batch.obs["task"], batch.next_obs["task"])  # a task holds for its whole episode
