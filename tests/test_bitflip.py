import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

from taskrl.envs import BitFlip, is_goal_env


def test_reset_gives_random_start_and_random_goal():
    env = BitFlip(12, num_envs=256, seed=0)
    obs = env.reset(seed=0)
    assert set(obs) == {"observation", "achieved_goal", "desired_goal"}
    assert obs["observation"].shape == (256, 12) and obs["observation"].dtype == torch.int8
    goals = obs["desired_goal"]
    # Not the fixed all-ones target: goals differ between copies and bits are balanced.
    assert len({tuple(g.tolist()) for g in goals}) > 200
    assert 0.4 < goals.float().mean() < 0.6
    assert torch.equal(obs["observation"], obs["achieved_goal"])


def test_step_flips_exactly_one_bit_and_rewards_only_the_goal():
    env = BitFlip(5, num_envs=3, seed=1)
    obs = env.reset(seed=1)
    before = obs["observation"].clone()
    action = torch.tensor([0, 2, 4])
    nxt, reward, terminated, truncated, info = env.step(action)
    final = info["final_obs"]["observation"]
    assert ((final != before).sum(dim=1) == 1).all()
    assert (final[torch.arange(3), action] != before[torch.arange(3), action]).all()
    success = (final == obs["desired_goal"]).all(dim=1)
    assert torch.equal(reward, success.float() - 1.0)
    assert torch.equal(info["is_success"], success)
    assert torch.equal(terminated, success)


def test_success_terminates_and_resets_in_the_same_step():
    env = BitFlip(4, num_envs=1, seed=2)
    obs = env.reset(seed=2)
    diff = (obs["observation"] != obs["desired_goal"])[0].nonzero().flatten().tolist()
    if not diff:
        pytest.skip("start equals goal for this seed")
    for i, bit in enumerate(diff):
        nxt, reward, terminated, truncated, info = env.step(torch.tensor([bit]))
        last = i == len(diff) - 1
        assert bool(terminated[0]) == last and not bool(truncated[0])
        assert float(reward[0]) == (0.0 if last else -1.0)
    # The returned observation already belongs to the next episode; the final one is in info.
    assert torch.equal(info["final_obs"]["achieved_goal"], obs["desired_goal"])
    assert int(env.t[0]) == 0


def test_time_limit_truncates_not_terminates():
    env = BitFlip(6, num_envs=4, seed=3, terminate_on_success=False)
    env.reset(seed=3)
    for t in range(6):
        _, _, terminated, truncated, _ = env.step(torch.zeros(4, dtype=torch.long))
        assert not terminated.any()
        assert bool(truncated.all()) == (t == 5)


def test_compute_reward_is_vectorised_and_matches_the_definition():
    env = BitFlip(8)
    a = torch.randint(0, 2, (100, 8), dtype=torch.int8)
    d = a.clone()
    d[::2, 3] ^= 1
    r = env.compute_reward(a, d, None)
    assert r.shape == (100,)
    assert torch.equal(r, torch.tensor([-1.0, 0.0] * 50))
    assert is_goal_env(env)


@pytest.mark.parametrize("bad", [0, -3])
def test_bad_n_bits_is_rejected(bad):
    with pytest.raises(ValueError, match="n_bits must be >= 1"):
        BitFlip(bad)


def test_registered_with_gymnasium_and_passes_the_env_checker():
    env = gym.make("taskrl/BitFlip-v0", n_bits=7)
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert obs["desired_goal"].shape == (7,)
    r = env.unwrapped.compute_reward(np.zeros((3, 7)), np.zeros((3, 7)), None)
    assert r.tolist() == [0.0, 0.0, 0.0]
