import gymnasium as gym
import numpy as np
import pytest
import torch
import torch.nn.functional as F
from gymnasium.utils.env_checker import check_env

from taskrl.agents.sac import SACAgent, SACConfig
from taskrl.envs import GymnasiumVectorEnv, MultiTaskPointReach, is_goal_env
from taskrl.envs.multitask_point import DEFAULT_REGIONS
from taskrl.replay.batch import Batch
from taskrl.training.per_task import evaluate_per_task


def oracle(env: MultiTaskPointReach):
    """Moves straight to the centre of the observed task's region."""
    return lambda obs: ((env.centres[obs["task"]] - obs["observation"]) / env.max_speed).clamp(-1, 1)


def test_spaces_tasks_and_descriptions():
    env = MultiTaskPointReach(num_envs=6, seed=0)
    assert env.task_set.names == ["top-left", "top-right", "bottom-left", "bottom-right", "centre"]
    assert all(d.endswith(".") and len(d.split()) >= 5 for d in env.task_set.descriptions)
    obs = env.reset(seed=0)
    assert set(obs) == {"observation", "task"} and not is_goal_env(env)
    assert obs["observation"].shape == (6, 2) and obs["observation"].dtype == torch.float32
    assert obs["task"].shape == (6,) and obs["task"].dtype == torch.int64
    assert env.single_observation_space["task"] == gym.spaces.Discrete(5)
    assert env.single_observation_space["observation"].shape == (2,) and env.horizon == 50
    nxt, reward, terminated, truncated, info = env.step(torch.zeros(6, 2))
    assert reward.shape == (6,) and reward.dtype == torch.float32
    assert terminated.dtype == truncated.dtype == info["is_success"].dtype == torch.bool
    assert {k: (v.shape, v.dtype) for k, v in info["final_obs"].items()} == {k: (v.shape, v.dtype) for k, v in nxt.items()}


def test_uniform_tasks_fixed_tasks_and_seeding():
    env = MultiTaskPointReach(num_envs=500, seed=1)
    tasks = env.reset(seed=1)["task"]
    counts = torch.bincount(tasks, minlength=5)
    assert (counts > 60).all()  # every task drawn, roughly uniformly
    assert torch.equal(env.reset(seed=1)["task"], tasks) and not torch.equal(env.reset(seed=2)["task"], tasks)
    fixed = MultiTaskPointReach(num_envs=7, task_sampling="fixed", horizon=2, seed=0)
    obs = fixed.reset(seed=0)
    assert obs["task"].tolist() == [0, 1, 2, 3, 4, 0, 1] and fixed.slot_tasks.tolist() == [0, 1, 2, 3, 4, 0, 1]
    for _ in range(4):  # across autoresets
        obs, *_ = fixed.step(torch.zeros(7, 2))
        assert obs["task"].tolist() == [0, 1, 2, 3, 4, 0, 1]
    assert env.slot_tasks is None


def test_rewards_success_and_relabelling_with_any_task():
    env = MultiTaskPointReach(num_envs=5, task_sampling="fixed", seed=0)
    env.reset(seed=0)
    env.position = env.centres.clone() + torch.tensor([0.05, 0.0])  # inside each region
    _, reward, terminated, _, info = env.step(torch.zeros(5, 2))
    assert info["is_success"].all() and (reward == 0).all() and not terminated.any()
    env.position = env.centres.roll(1, dims=0).clone()  # at another region's centre
    _, reward, _, _, info = env.step(torch.zeros(5, 2))
    assert not info["is_success"].any() and (reward == -1).all()
    position = torch.tensor([[-0.7, 0.7], [-0.7, 0.7]])
    assert env.compute_task_reward(position, torch.tensor([0, 3])).tolist() == [0.0, -1.0]
    assert env.compute_task_success(position, torch.tensor([0, 4])).tolist() == [True, False]
    dense = MultiTaskPointReach(num_envs=2, reward="dense", seed=0)
    d = dense.compute_task_reward(torch.zeros(2, 2), torch.tensor([4, 1]))
    torch.testing.assert_close(d, torch.tensor([0.0, -((0.7**2 * 2) ** 0.5)]))


def test_horizon_truncation_final_obs_and_terminate_on_success():
    env = MultiTaskPointReach(num_envs=3, horizon=4, seed=3)
    obs = env.reset(seed=3)
    for t in range(4):
        before = obs
        obs, _, terminated, truncated, info = env.step(torch.ones(3, 2))
        assert not terminated.any() and bool(truncated.all()) == (t == 3)
    torch.testing.assert_close(info["final_obs"]["observation"], (before["observation"] + 0.1).clamp(-1, 1))
    assert torch.equal(info["final_obs"]["task"], before["task"])
    stop = MultiTaskPointReach(num_envs=5, task_sampling="fixed", terminate_on_success=True, seed=0)
    stop.reset(seed=0)
    stop.position = stop.centres.clone()
    _, _, terminated, truncated, _ = stop.step(torch.zeros(5, 2))
    assert terminated.all() and not truncated.any()


def test_bad_arguments_are_rejected():
    with pytest.raises(ValueError, match="task_sampling"):
        MultiTaskPointReach(task_sampling="roundrobin")
    with pytest.raises(ValueError, match="reward"):
        MultiTaskPointReach(reward="shaped")
    with pytest.raises(ValueError, match="outside the box"):
        MultiTaskPointReach(regions=[("far", "Go far away.", (2.0, 0.0))])
    with pytest.raises(ValueError, match="radius"):
        MultiTaskPointReach(radius=0)


def test_gymnasium_registration_and_the_vector_adapter():
    env = gym.make("taskrl/MultiTaskPointReach-v0")
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=0, options={"task": "centre"})
    assert obs["task"] == 4 and env.observation_space.contains(obs)
    obs, reward, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
    assert isinstance(info["is_success"], bool) and env.spec.max_episode_steps == 50
    with pytest.raises(KeyError, match="allowed names"):
        env.reset(options={"task": "middle"})
    env.close()
    with GymnasiumVectorEnv("taskrl/MultiTaskPointReach-v0", num_envs=3) as venv:
        obs = venv.reset(seed=0)
        assert obs["task"].dtype == torch.int64 and obs["observation"].dtype == torch.float32 and venv.horizon == 50
        _, reward, _, _, info = venv.step(torch.zeros(3, 2))
        assert reward.shape == (3,) and info["is_success"].dtype == torch.bool


def test_per_task_evaluation_of_scripted_policies(tmp_path):
    env = MultiTaskPointReach(num_envs=10, task_sampling="fixed", seed=0)
    result = evaluate_per_task(oracle(env), env, episodes_per_task=4, seed=0, save_to=tmp_path / "eval.json")
    assert result["mean_success_rate"] == 1.0 and not result["distinct_goals"]
    assert [r["episodes"] for r in result["tasks"].values()] == [4] * 5
    assert (tmp_path / "eval.json").exists()
    # Ignoring the task: always heading for the top-left region ends there whatever the task.
    uniform = MultiTaskPointReach(num_envs=8, seed=0)  # tasks counted from observations
    go_top_left = oracle(uniform)
    top_left = lambda obs: go_top_left({**obs, "task": torch.zeros_like(obs["task"])})  # noqa: E731
    result = evaluate_per_task(top_left, uniform, episodes_per_task=6, seed=0, success="final")
    rates = {k: v["success_rate"] for k, v in result["tasks"].items()}
    assert rates == {"top-left": 1.0, "top-right": 0.0, "bottom-left": 0.0, "bottom-right": 0.0, "centre": 0.0}
    assert result["mean_success_rate"] == pytest.approx(0.2) and result["success"] == "at the final step"
    anywhere = evaluate_per_task(top_left, uniform, episodes_per_task=6, seed=0)  # passing through counts
    assert anywhere["tasks"]["top-left"]["success_rate"] == 1.0 and anywhere["mean_success_rate"] >= 0.2


def _train_sac(conditioned: bool, seed: int = 0, env_steps: int = 250) -> float:
    """SAC on the dense-reward task, with or without a one-hot of the task in its input."""
    torch.manual_seed(seed)
    k = len(DEFAULT_REGIONS)
    env = MultiTaskPointReach(num_envs=16, reward="dense", horizon=30, seed=seed)
    keys = ("observation", "onehot") if conditioned else ("observation",)
    agent = SACAgent(
        keys,
        2 + (k if conditioned else 0),
        env.single_action_space,
        SACConfig(lr=3e-3, gamma=0.8, hidden_sizes=(64, 64), init_alpha=0.05, normalize_inputs=False),
    )

    def with_onehot(obs):
        return {**obs, "onehot": F.one_hot(obs["task"], k).float()}

    store = {"obs": [], "action": [], "reward": [], "next": [], "task": []}
    obs = env.reset(seed=seed)
    for step in range(env_steps):
        action = agent.act(with_onehot(obs), explore=True) if step > 10 else torch.rand(16, 2) * 2 - 1
        nxt, reward, terminated, truncated, info = env.step(action)
        for key, value in (
            ("obs", obs["observation"]),
            ("action", action),
            ("reward", reward),
            ("next", info["final_obs"]["observation"]),
            ("task", obs["task"]),
        ):
            store[key].append(value)
        obs = nxt
        if step >= 10:
            data = {key: torch.cat(v) for key, v in store.items()}
            for _ in range(2):
                i = torch.randint(data["reward"].shape[0], (256,))
                n = i.shape[0]
                agent.update(
                    Batch(
                        obs=with_onehot({"observation": data["obs"][i], "task": data["task"][i]}),
                        action=data["action"][i],
                        reward=data["reward"][i],
                        next_obs=with_onehot({"observation": data["next"][i], "task": data["task"][i]}),
                        terminated=torch.zeros(n, dtype=torch.bool),
                        truncated=torch.zeros(n, dtype=torch.bool),
                        episode=torch.zeros(n, dtype=torch.long),
                        step=torch.zeros(n, dtype=torch.long),
                    )
                )
    eval_env = MultiTaskPointReach(num_envs=20, task_sampling="fixed", seed=123)
    result = evaluate_per_task(lambda o: agent.act(with_onehot(o)), eval_env, episodes_per_task=4, seed=123, success="final")
    return result["mean_success_rate"]


@pytest.mark.slow
def test_one_hot_conditioning_solves_what_an_unconditioned_policy_cannot():
    assert _train_sac(conditioned=True) >= 0.9
    assert _train_sac(conditioned=False) <= 0.4  # at most 1/K = 0.2 in expectation
