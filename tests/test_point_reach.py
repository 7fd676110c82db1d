import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

from taskrl.envs import PointReach, is_goal_env


def test_spaces_shapes_and_dtypes():
    env = PointReach(num_envs=5, seed=0)
    obs = env.reset(seed=0)
    assert set(obs) == {"observation", "achieved_goal", "desired_goal"}
    for k, v in obs.items():
        assert v.shape == (5, 2) and v.dtype == torch.float32 and v.device == env.device
        assert env.single_observation_space[k].dtype == np.float32
        assert ((v >= -1) & (v <= 1)).all()
    assert torch.equal(obs["observation"], obs["achieved_goal"])
    space = env.single_action_space
    assert isinstance(space, gym.spaces.Box) and space.shape == (2,) and space.dtype == np.float32
    assert env.horizon == 50 and is_goal_env(env)
    nxt, reward, terminated, truncated, info = env.step(torch.zeros(5, 2))
    assert reward.shape == (5,) and reward.dtype == torch.float32
    assert terminated.dtype == torch.bool and truncated.dtype == torch.bool
    assert info["is_success"].dtype == torch.bool and info["is_success"].shape == (5,)
    assert {k: v.shape for k, v in info["final_obs"].items()} == {k: v.shape for k, v in nxt.items()}


def test_random_starts_and_goals_differ():
    env = PointReach(num_envs=256, seed=1)
    obs = env.reset(seed=1)
    goals, starts = obs["desired_goal"], obs["achieved_goal"]
    assert len({tuple(g.tolist()) for g in goals}) == 256
    assert not torch.equal(goals, starts)
    assert goals.min() < -0.8 and goals.max() > 0.8  # uniform over the whole box
    assert abs(float(goals.mean())) < 0.1
    # Reseeding repeats, a different seed does not.
    assert torch.equal(env.reset(seed=1)["desired_goal"], goals)
    assert not torch.equal(env.reset(seed=2)["desired_goal"], goals)


def test_moves_by_action_times_max_speed_and_clips():
    env = PointReach(num_envs=3, max_speed=0.1, seed=2)
    env.reset(seed=2)
    env.position = torch.tensor([[0.0, 0.0], [0.95, -0.95], [0.5, 0.5]])
    action = torch.tensor([[0.5, -1.0], [1.0, -1.0], [3.0, -7.0]])  # last row is out of range
    _, _, _, _, info = env.step(action)
    pos = info["final_obs"]["achieved_goal"]
    expected = torch.tensor([[0.05, -0.1], [1.0, -1.0], [0.6, 0.4]])
    torch.testing.assert_close(pos, expected)
    torch.testing.assert_close(info["final_obs"]["observation"], expected)


def test_sparse_and_dense_rewards_and_success_threshold():
    for mode in ("sparse", "dense"):
        env = PointReach(num_envs=4, reward=mode, seed=3)
        env.reset(seed=3)
        env.position = torch.zeros(4, 2)
        # Distances after a zero action: 0, 0.04, 0.0501, 0.5.
        env.goal = torch.tensor([[0.0, 0.0], [0.04, 0.0], [0.0, 0.0501], [0.3, 0.4]])
        _, reward, terminated, _, info = env.step(torch.zeros(4, 2))
        assert info["is_success"].tolist() == [True, True, False, False]
        assert not terminated.any()
        if mode == "sparse":
            assert reward.tolist() == [0.0, 0.0, -1.0, -1.0]
        else:
            torch.testing.assert_close(reward, -torch.tensor([0.0, 0.04, 0.0501, 0.5]))


def test_truncates_at_horizon_and_final_obs_differs_from_reset_obs():
    env = PointReach(num_envs=4, horizon=7, seed=4)
    obs = env.reset(seed=4)
    action = torch.ones(4, 2)
    for t in range(7):
        start = obs
        obs, _, terminated, truncated, info = env.step(action)
        assert not terminated.any()
        assert bool(truncated.all()) == (t == 6)
        if t < 6:  # nothing ended: final_obs is the returned observation
            for k in obs:
                assert torch.equal(info["final_obs"][k], obs[k])
    # The final observation is one step from the last one; the returned one is a fresh episode.
    torch.testing.assert_close(info["final_obs"]["achieved_goal"], (start["achieved_goal"] + 0.1).clamp(-1, 1))
    assert torch.equal(info["final_obs"]["desired_goal"], start["desired_goal"])
    assert not torch.equal(obs["desired_goal"], start["desired_goal"])
    assert int(env.t.max()) == 0


def test_terminate_on_success_option():
    env = PointReach(num_envs=2, terminate_on_success=True, seed=5)
    env.reset(seed=5)
    env.position = torch.zeros(2, 2)
    env.goal = torch.tensor([[0.0, 0.0], [0.5, 0.5]])
    obs, _, terminated, truncated, info = env.step(torch.zeros(2, 2))
    assert terminated.tolist() == [True, False] and not truncated.any()
    assert torch.equal(info["final_obs"]["desired_goal"][0], torch.zeros(2))
    assert not torch.equal(obs["desired_goal"][0], torch.zeros(2))  # reset in the same step
    a = torch.tensor([[0.0, 0.0], [0.0, 0.0]])
    assert env.compute_terminated(a, env.goal.new_tensor([[0.01, 0.0], [1.0, 0.0]])).tolist() == [True, False]
    assert not PointReach(seed=0).compute_terminated(a, a).any()


def test_compute_reward_is_vectorised_and_matches_step_rewards():
    for mode in ("sparse", "dense"):
        env = PointReach(num_envs=64, reward=mode, seed=6)
        env.reset(seed=6)
        g = torch.Generator().manual_seed(0)
        for _ in range(5):
            _, reward, _, _, info = env.step(torch.rand(64, 2, generator=g) * 2 - 1)
            final = info["final_obs"]
            torch.testing.assert_close(env.compute_reward(final["achieved_goal"], final["desired_goal"], None), reward)
        a = torch.rand(1000, 2) * 2 - 1
        d = a + torch.tensor([0.03, 0.0])
        r = env.compute_reward(a, d, None)
        assert r.shape == (1000,)
        expected = torch.zeros(1000) if mode == "sparse" else torch.full((1000,), -0.03)
        torch.testing.assert_close(r, expected)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"num_envs": 0}, "num_envs"),
        ({"horizon": 0}, "horizon"),
        ({"reward": "shaped"}, "reward"),
        ({"max_speed": 0.0}, "max_speed"),
        ({"max_speed": float("nan")}, "max_speed"),
        ({"distance_threshold": -1.0}, "distance_threshold"),
    ],
)
def test_bad_arguments_name_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        PointReach(**kwargs)


def test_registered_with_gymnasium_and_passes_the_env_checker():
    env = gym.make("taskrl/PointReach-v0")
    assert env.spec.max_episode_steps == 50
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert obs["desired_goal"].shape == (2,) and obs["desired_goal"].dtype == np.float32
    steps = 0
    truncated = False
    while not truncated:
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert not terminated and isinstance(info["is_success"], bool)
        steps += 1
    assert steps == 50
    # Vectorised numpy compute_reward equal to the torch one.
    u = env.unwrapped
    a = np.random.default_rng(0).uniform(-1, 1, (100, 2)).astype(np.float32)
    d = np.random.default_rng(1).uniform(-1, 1, (100, 2)).astype(np.float32)
    d[:10] = a[:10] + 0.01
    r = u.compute_reward(a, d, None)
    assert r.shape == (100,) and r.dtype == np.float32 and (r[:10] == 0).all()
    np.testing.assert_allclose(r, PointReach().compute_reward(torch.from_numpy(a), torch.from_numpy(d)).numpy())
    dense = gym.make("taskrl/PointReach-v0", reward="dense").unwrapped
    np.testing.assert_allclose(dense.compute_reward(a, d, None), -np.linalg.norm(a - d, axis=-1), rtol=1e-6)
