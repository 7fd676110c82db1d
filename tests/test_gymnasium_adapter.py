import gymnasium as gym
import numpy as np
import pytest
import torch

from taskrl.envs import GymnasiumGoalEnv, PointReach, is_goal_env


def _point_reach(num_envs: int = 3, **kwargs) -> GymnasiumGoalEnv:
    return GymnasiumGoalEnv("taskrl/PointReach-v0", num_envs=num_envs, **kwargs)


def test_shapes_dtypes_devices_and_horizon():
    with _point_reach(3) as env:
        assert env.horizon == 50 and env.num_envs == 3 and is_goal_env(env)
        assert isinstance(env.single_action_space, gym.spaces.Box)
        obs = env.reset(seed=0)
        assert set(obs) == set(env.single_observation_space.spaces)
        for v in obs.values():
            assert v.shape == (3, 2) and v.dtype == torch.float32 and v.device == env.device
        nxt, reward, terminated, truncated, info = env.step(torch.zeros(3, 2))
        assert reward.shape == (3,) and reward.dtype == torch.float32
        assert terminated.dtype == truncated.dtype == info["is_success"].dtype == torch.bool
        assert all(t.device == env.device for t in (reward, terminated, truncated, info["is_success"]))
        assert {k: (v.shape, v.dtype) for k, v in info["final_obs"].items()} == {k: (v.shape, v.dtype) for k, v in nxt.items()}


def test_seeding_repeats_and_matches_async():
    with _point_reach(2) as a, _point_reach(2) as b, _point_reach(2, vector_strategy="async") as c:
        oa, ob, oc = a.reset(seed=7), b.reset(seed=7), c.reset(seed=7)
        for k in oa:
            assert torch.equal(oa[k], ob[k]) and torch.equal(oa[k], oc[k])
        assert not torch.equal(oa["desired_goal"][0], oa["desired_goal"][1])  # copy i gets seed + i
        action = torch.tensor([[0.5, -0.5], [1.0, 1.0]])
        ra, rc = a.step(action), c.step(action)
        for k in oa:
            assert torch.equal(ra[0][k], rc[0][k]) and torch.equal(ra[4]["final_obs"][k], rc[4]["final_obs"][k])
        assert torch.equal(ra[1], rc[1])
        r = c.compute_reward(oc["achieved_goal"], oc["desired_goal"])  # async: a local instance's function
        assert r.shape == (2,)


def test_time_limit_final_obs_differs_from_the_reset_obs():
    with _point_reach(3, max_episode_steps=4) as env:
        assert env.horizon == 4
        obs = env.reset(seed=1)
        for t in range(4):
            before = obs
            obs, reward, terminated, truncated, info = env.step(torch.ones(3, 2))
            assert not terminated.any() and bool(truncated.all()) == (t == 3)
            if t < 3:
                for k in obs:
                    assert torch.equal(info["final_obs"][k], obs[k])
        final = info["final_obs"]
        torch.testing.assert_close(final["achieved_goal"], (before["achieved_goal"] + 0.1).clamp(-1, 1))
        assert torch.equal(final["desired_goal"], before["desired_goal"])
        assert not torch.equal(obs["desired_goal"], before["desired_goal"])  # a new episode began


def test_mixed_autoreset_rows_and_success_from_the_finished_step():
    # A wide success radius with termination: some copies end at step 1, others do not.
    kwargs = {"terminate_on_success": True, "distance_threshold": 0.9}
    with _point_reach(8, env_kwargs=kwargs) as env:
        obs = env.reset(seed=3)
        nxt, reward, terminated, truncated, info = env.step(torch.zeros(8, 2))
        ended = terminated | truncated
        assert ended.any() and not ended.all(), "seed should give a mix of finished and running copies"
        final = info["final_obs"]
        for k in nxt:
            assert torch.equal(final[k][~ended], nxt[k][~ended])
        # Finished rows: the state the step led to (start position, old goal), not the reset one.
        assert torch.equal(final["desired_goal"][ended], obs["desired_goal"][ended])
        assert torch.equal(final["achieved_goal"], obs["achieved_goal"])
        assert not torch.equal(nxt["desired_goal"][ended], obs["desired_goal"][ended])
        assert torch.equal(info["is_success"], terminated)  # ended by success: read from final_info
        torch.testing.assert_close(env.compute_reward(final["achieved_goal"], final["desired_goal"]), reward)
        assert torch.equal(env.compute_terminated(final["achieved_goal"], final["desired_goal"]), terminated)


def test_compute_reward_equals_the_envs_own():
    with _point_reach(2, env_kwargs={"reward": "dense"}) as env:
        rng = np.random.default_rng(0)
        a, d = rng.uniform(-1, 1, (50, 2)), rng.uniform(-1, 1, (50, 2))
        own = env.goal_env.compute_reward(a, d, None)
        r = env.compute_reward(torch.from_numpy(a), torch.from_numpy(d), None)
        assert r.shape == (50,) and r.dtype == torch.float32
        np.testing.assert_allclose(r.numpy(), own, rtol=1e-6)
        native = PointReach(reward="dense").compute_reward(torch.from_numpy(a), torch.from_numpy(d))
        np.testing.assert_allclose(r.numpy(), native.numpy(), rtol=1e-6)
        t = env.compute_terminated(torch.from_numpy(a), torch.from_numpy(d))
        assert t.shape == (50,) and t.dtype == torch.bool and not t.any()


def test_non_goal_env_and_bad_arguments_are_rejected():
    with pytest.raises(ValueError, match="not a goal env"):
        GymnasiumGoalEnv("CartPole-v1")
    with pytest.raises(ValueError, match="vector_strategy"):
        GymnasiumGoalEnv("taskrl/PointReach-v0", vector_strategy="threads")
    with pytest.raises(ValueError, match="num_envs"):
        GymnasiumGoalEnv("taskrl/PointReach-v0", num_envs=0)
    with pytest.raises(ValueError, match="not registered"):
        GymnasiumGoalEnv("NoSuchEnv-v9")
    with _point_reach(2, success_key="success") as env:  # Meta-World's key, absent here
        env.reset(seed=0)
        with pytest.raises(ValueError, match="success_key='success'"):
            env.step(torch.zeros(2, 2))


def test_fetch_reach():
    pytest.importorskip("gymnasium_robotics")
    with GymnasiumGoalEnv("FetchReach-v4", num_envs=2) as env:
        assert env.horizon == 50
        space = env.single_observation_space
        assert space["observation"].shape == (10,) and space["observation"].dtype == np.float32
        obs = env.reset(seed=0)
        assert obs["observation"].shape == (2, 10) and obs["observation"].dtype == torch.float32
        g = torch.Generator().manual_seed(0)
        for t in range(50):
            before = obs
            obs, reward, terminated, truncated, info = env.step(torch.rand(2, 4, generator=g) * 2 - 1)
            final = info["final_obs"]
            # Fetch's sparse reward is its own compute_reward of the state the step led to.
            torch.testing.assert_close(env.compute_reward(final["achieved_goal"], final["desired_goal"], None), reward)
            assert torch.equal(info["is_success"], reward == 0)
            if t < 49:
                assert not (terminated | truncated).any()
                assert all(torch.equal(final[k], obs[k]) for k in obs)
        assert truncated.all() and not terminated.any()
        assert torch.equal(final["desired_goal"], before["desired_goal"])
        assert not torch.equal(obs["desired_goal"], before["desired_goal"])  # reset goals
        a, d = final["achieved_goal"].double(), obs["desired_goal"].double()
        np.testing.assert_array_equal(env.compute_reward(a, d).numpy(), env.goal_env.compute_reward(a.numpy(), d.numpy(), None))
        done = env.compute_terminated(a, d)  # Fetch returns one scalar False: still one bool per row
        assert done.shape == (2,) and done.dtype == torch.bool and not done.any()


class _ScalarGoalEnv(gym.Env):
    """A goal env whose goal functions accept one goal at a time (not vectorised)."""

    def __init__(self):
        box = gym.spaces.Box(-1.0, 1.0, (2,), np.float64)
        self.observation_space = gym.spaces.Dict({"observation": box, "achieved_goal": box, "desired_goal": box})
        self.action_space = gym.spaces.Discrete(3)

    def _obs(self):
        return {"observation": self.pos.copy(), "achieved_goal": self.pos.copy(), "desired_goal": np.zeros(2)}

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.pos = self.np_random.uniform(-1, 1, 2)
        return self._obs(), {}

    def step(self, action):
        self.pos = self.pos * 0.5 if action == 1 else self.pos
        r = self.compute_reward(self.pos, np.zeros(2), None)
        return self._obs(), r, bool(self.compute_terminated(self.pos, np.zeros(2), None)), False, {"is_success": r == 0}

    def compute_reward(self, achieved_goal, desired_goal, info):
        return 0.0 if np.linalg.norm(achieved_goal - desired_goal) < 0.5 else -1.0

    def compute_terminated(self, achieved_goal, desired_goal, info):
        return bool(np.linalg.norm(achieved_goal - desired_goal) < 0.5)


def test_env_factory_and_non_vectorised_goal_functions():
    with GymnasiumGoalEnv(_ScalarGoalEnv, num_envs=2) as env:  # no time limit: it ends its own episodes
        assert env.horizon is None
    with GymnasiumGoalEnv(_ScalarGoalEnv, num_envs=2, max_episode_steps=3) as env:
        assert env.horizon == 3 and env.single_observation_space["observation"].dtype == np.float32
        env.reset(seed=0)
        _, reward, terminated, _, info = env.step(torch.tensor([1, 1]))
        final = info["final_obs"]
        torch.testing.assert_close(env.compute_reward(final["achieved_goal"], final["desired_goal"]), reward)
        assert torch.equal(env.compute_terminated(final["achieved_goal"], final["desired_goal"]), terminated)
        a = torch.tensor([[0.1, 0.0], [0.9, 0.0], [0.0, -0.2]])
        assert env.compute_reward(a, torch.zeros(3, 2)).tolist() == [0.0, -1.0, 0.0]
        assert env.compute_terminated(a, torch.zeros(3, 2)).tolist() == [True, False, True]
