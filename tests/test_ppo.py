import dataclasses
import json

import gymnasium as gym
import pytest
import torch

from taskrl.agents.ppo import (
    PPOAgent,
    PPOConfig,
    clipped_surrogate,
    gae,
    gaussian_entropy,
    gaussian_log_prob,
    reward_to_go,
)
from taskrl.checkpoint import flatten_state, unflatten_state
from taskrl.conditioning.networks import ConditioningConfig, make_conditioning
from taskrl.config import field_docs
from taskrl.envs import MultiTaskPointReach
from taskrl.envs.base import BatchedEnv
from taskrl.training.bookkeeping import Bookkeeping
from taskrl.training.offpolicy import LoopState
from taskrl.training.onpolicy import OnPolicyLoop, collect_rollout
from taskrl.training.per_task import evaluate_per_task

# Two environments, three steps. Env 0 is truncated at t=1 (time limit: bootstrap from
# V(final_obs) = 10) and runs on after the rollout (bootstrap from last_value = 4). Env 1
# terminates at t=0 (no bootstrap: its final_value 99 must be ignored).
REWARD = torch.tensor([[1.0, 1.0], [2.0, 1.0], [3.0, 1.0]])
VALUE = torch.tensor([[0.5, 2.0], [1.0, 1.0], [1.5, 0.5]])
FINAL_VALUE = torch.tensor([[0.0, 99.0], [10.0, 0.0], [0.0, 0.0]])
LAST_VALUE = torch.tensor([4.0, 2.0])
TERMINATED = torch.tensor([[False, True], [False, False], [False, False]])
TRUNCATED = torch.tensor([[False, False], [True, False], [False, False]])
GAMMA, LAM = 0.9, 0.8


def test_gae_bootstraps_truncations_and_not_terminations():
    adv = gae(REWARD, VALUE, FINAL_VALUE, LAST_VALUE, TERMINATED, TRUNCATED, GAMMA, LAM)
    # env 0: delta_2 = 3 + .9*4 - 1.5 = 5.1; delta_1 = 2 + .9*10 - 1 = 10 (episode ends: no carry);
    #        delta_0 = 1 + .9*1 - .5 = 1.4, A_0 = 1.4 + .9*.8*10 = 8.6
    # env 1: delta_2 = 1 + .9*2 - .5 = 2.3; delta_1 = 1 + .9*.5 - 1 = .45, A_1 = .45 + .72*2.3 = 2.106;
    #        A_0 = 1 + 0 - 2 = -1 (terminated)
    torch.testing.assert_close(adv, torch.tensor([[8.6, -1.0], [10.0, 2.106], [5.1, 2.3]]))


def test_reward_to_go_and_its_relation_to_gae():
    returns = reward_to_go(REWARD, FINAL_VALUE, LAST_VALUE, TERMINATED, TRUNCATED, GAMMA)
    # env 0: G_2 = 3 + .9*4 = 6.6, G_1 = 2 + .9*10 = 11, G_0 = 1 + .9*11 = 10.9
    # env 1: G_2 = 1 + .9*2 = 2.8, G_1 = 1 + .9*2.8 = 3.52, G_0 = 1
    torch.testing.assert_close(returns, torch.tensor([[10.9, 1.0], [11.0, 3.52], [6.6, 2.8]]))
    adv1 = gae(REWARD, VALUE, FINAL_VALUE, LAST_VALUE, TERMINATED, TRUNCATED, GAMMA, 1.0)
    torch.testing.assert_close(adv1 + VALUE, returns)  # lambda = 1 is reward-to-go minus the value


def test_clipped_surrogate_by_hand():
    ratio = torch.tensor([1.5, 0.5, 1.1, 0.7])
    advantage = torch.tensor([1.0, 1.0, -2.0, -1.0])
    old = torch.tensor([0.3, -1.0, 0.2, -0.4])
    log_prob = (old + ratio.log()).requires_grad_(True)
    loss, approx_kl, clip_fraction = clipped_surrogate(log_prob, old, advantage, 0.2)
    # min(1.5, 1.2) + min(0.5, 0.8) + min(-2.2, -2.2) + min(-0.7, -0.8) = -1.3 -> loss 1.3 / 4
    torch.testing.assert_close(loss, torch.tensor(0.325))
    torch.testing.assert_close(clip_fraction, torch.tensor(0.75))  # |rho - 1| > 0.2 for 1.5, 0.5, 0.7
    torch.testing.assert_close(approx_kl, ((ratio - 1) - ratio.log()).mean())
    loss.backward()
    # Clipped terms chosen by the min pass no gradient; the others pass -rho A / 4.
    torch.testing.assert_close(log_prob.grad, torch.tensor([0.0, -0.125, 0.55, 0.0]))


def test_gaussian_and_categorical_log_probs_match_torch_distributions():
    g = torch.Generator().manual_seed(0)
    x, mean = torch.randn(6, 3, generator=g), torch.randn(6, 3, generator=g)
    log_std = torch.randn(3, generator=g).expand(6, 3)
    normal = torch.distributions.Normal(mean, log_std.exp())
    torch.testing.assert_close(gaussian_log_prob(x, mean, log_std), normal.log_prob(x).sum(-1))
    torch.testing.assert_close(gaussian_entropy(log_std), normal.entropy().sum(-1))

    # The agent: explore's log-prob is that of the unclipped sample; the env action is clipped.
    box = gym.spaces.Box(-2.0, 2.0, shape=(2,))
    agent = PPOAgent(("observation",), 2, box, PPOConfig(init_log_std=1.0, normalize_inputs=False))
    obs = {"observation": torch.randn(256, 2, generator=g)}
    env_action, action, log_prob, value = agent.rollout_step(obs, g)
    mean = agent.policy_net(obs["observation"])
    expected = torch.distributions.Normal(mean, agent.log_std.exp()).log_prob(action).sum(-1)
    torch.testing.assert_close(log_prob, expected)
    assert action.abs().max() > 1.0  # std e in unit space: some samples leave the box ...
    torch.testing.assert_close(env_action, 2.0 * action.clamp(-1, 1))  # ... and are clipped to it
    torch.testing.assert_close(value, agent.value_net(obs["observation"]).squeeze(-1))
    torch.testing.assert_close(agent.act(obs), 2.0 * mean.clamp(-1, 1))  # exploration 0: the mean

    discrete = PPOAgent(("observation",), 2, gym.spaces.Discrete(4, start=1), PPOConfig())
    env_action, action, log_prob, _ = discrete.rollout_step(obs, g)
    logits = discrete.policy_net(obs["observation"])
    torch.testing.assert_close(log_prob, torch.distributions.Categorical(logits=logits).log_prob(action))
    assert torch.equal(env_action, action + 1) and torch.equal(discrete.act(obs), logits.argmax(-1) + 1)


def test_first_step_sees_the_policy_that_acted_and_validation():
    env = MultiTaskPointReach(num_envs=8, reward="dense", seed=0)
    torch.manual_seed(0)
    cfg = PPOConfig(epochs=1, minibatches=1, rollout_steps=10, normalize_advantages=False)
    agent = PPOAgent(("observation",), 2, env.single_action_space, cfg)
    rollout, *_ = collect_rollout(env, agent, env.reset(seed=0), 10, torch.Generator().manual_seed(0))
    adv, _ = agent.advantages(rollout)
    metrics = agent.update(rollout)
    # rho = 1 exactly on the only step: no KL, nothing clipped, loss = -mean(A).
    assert metrics["approx_kl"].item() == 0.0 and metrics["clip_fraction"].item() == 0.0
    torch.testing.assert_close(metrics["policy_loss"], -adv.mean())
    assert set(metrics) >= {"policy_loss", "value_loss", "entropy", "approx_kl", "clip_fraction", "explained_variance"}
    assert agent.updates == 1
    # The CLI reads one help line per field.
    assert set(field_docs(PPOConfig)) == {f.name for f in dataclasses.fields(PPOConfig)}
    with pytest.raises(ValueError, match="estimator"):
        PPOAgent(("observation",), 2, env.single_action_space, PPOConfig(estimator="a2c"))
    with pytest.raises(ValueError, match="value_coef"):
        PPOAgent(("observation",), 2, env.single_action_space, PPOConfig(value_coef=0.0))


def test_collection_bootstraps_truncations_from_the_final_observation():
    env = MultiTaskPointReach(num_envs=4, reward="dense", horizon=3, seed=0)
    torch.manual_seed(0)
    cond = make_conditioning(ConditioningConfig(task_encoder="onehot"), 5)
    agent = PPOAgent(("observation",), 2, env.single_action_space, PPOConfig(), conditioning=cond)
    finals = []
    step = env.step

    def recording_step(action):
        out = step(action)
        finals.append(out[4]["final_obs"])
        return out

    env.step = recording_step
    rollout, next_obs, ended, succeeded = collect_rollout(env, agent, env.reset(seed=0), 5)
    assert rollout.reward.shape == (5, 4) and rollout.obs["task"].shape == (5, 4) and rollout.action.shape == (5, 4, 2)
    assert rollout.truncated[2].all() and not rollout.truncated[[0, 1, 3, 4]].any() and int(ended) == 4
    torch.testing.assert_close(rollout.final_value[2], agent.value(finals[2]))
    assert (rollout.final_value[[0, 1, 3, 4]] == 0).all()
    # After the truncation the env reset: V(final_obs) is not the value of the next (reset) state.
    assert not torch.allclose(rollout.final_value[2], rollout.value[3])
    torch.testing.assert_close(rollout.last_value, agent.value(next_obs))


def test_state_dict_round_trip_through_a_checkpoint():
    env = MultiTaskPointReach(num_envs=8, reward="dense", seed=0)
    cond = lambda: make_conditioning(ConditioningConfig(task_encoder="embedding", embedding_dim=4), 5)  # noqa: E731
    torch.manual_seed(0)
    agent = PPOAgent(("observation",), 2, env.single_action_space, PPOConfig(rollout_steps=8), conditioning=cond())
    obs = env.reset(seed=0)
    for _ in range(2):
        rollout, obs, *_ = collect_rollout(env, agent, obs, 8, torch.Generator().manual_seed(1))
        agent.update(rollout, torch.Generator().manual_seed(2))
    tensors, skeleton = flatten_state(agent.state_dict())
    skeleton = json.loads(json.dumps(skeleton))  # JSON + tensors only
    torch.manual_seed(1)
    fresh = PPOAgent(("observation",), 2, env.single_action_space, PPOConfig(rollout_steps=8), conditioning=cond())
    assert not torch.allclose(fresh.act(obs), agent.act(obs))
    fresh.load_state_dict(unflatten_state(tensors, skeleton))
    torch.testing.assert_close(fresh.act(obs), agent.act(obs))
    torch.testing.assert_close(fresh.value(obs), agent.value(obs))
    assert fresh.updates == agent.updates == 2 * 10 * 4
    # The optimiser state came along too: the next update is the same.
    m1, m2 = (a.update(rollout, torch.Generator().manual_seed(3)) for a in (agent, fresh))
    torch.testing.assert_close(m1["policy_loss"], m2["policy_loss"])
    torch.testing.assert_close(fresh.act(obs), agent.act(obs))


def _final_success(agent, seed: int = 7, episodes: int = 8) -> float:
    eval_env = MultiTaskPointReach(num_envs=20, task_sampling="fixed", seed=seed)
    return evaluate_per_task(lambda o: agent.act(o), eval_env, episodes_per_task=episodes, seed=seed, success="final")[
        "mean_success_rate"
    ]


def _train_on_point(config: PPOConfig, total_steps: int, stop_at: float, seed: int = 0):
    """Train with the on-policy loop; stop early once the evaluation (seed 123) reaches ``stop_at``."""
    torch.manual_seed(seed)
    env = MultiTaskPointReach(num_envs=32, reward="dense", seed=seed)
    cond = make_conditioning(ConditioningConfig(task_encoder="onehot"), 5)
    agent = PPOAgent(("observation",), 2, env.single_action_space, config, conditioning=cond)
    eval_env = MultiTaskPointReach(num_envs=20, task_sampling="fixed", seed=123)

    def evaluate():
        result = evaluate_per_task(lambda o: agent.act(o), eval_env, episodes_per_task=4, seed=123, success="final")
        return {"success_rate": result["mean_success_rate"]}

    rows, checkpoints = [], []
    books = Bookkeeping(
        LoopState(),
        evaluate,
        rows.append,
        lambda state: checkpoints.append(state.env_steps),
        total_steps,
        8192,
        10**9,
        stop_at,
        env.device,
    )
    loop = OnPolicyLoop(env, agent, total_steps, books, torch.Generator().manual_seed(seed))
    state = loop.run(env_seed=seed)
    return agent, state, rows, checkpoints


@pytest.mark.slow
def test_ppo_with_one_hot_conditioning_solves_multitask_point_reach():
    agent, state, rows, checkpoints = _train_on_point(PPOConfig(), total_steps=200_000, stop_at=1.0)
    # Fails without the task (at most 1/5 at the final step) or without learning.
    assert _final_success(agent) >= 0.8
    assert rows[0]["success_rate"] <= 0.2 and state.env_steps < 200_000  # learnt, stopped early
    assert checkpoints == [64 * 32, state.env_steps]  # the first one is due at step 0 (LoopState), one at the end
    row = rows[-1]
    for column in (
        "env_steps",
        "updates",
        "wall_seconds",
        "success_rate",
        "train_success",
        "policy_loss",
        "value_loss",
        "entropy",
        "approx_kl",
        "clip_fraction",
        "explained_variance",
        "env_steps_per_s",
        "updates_per_s",
    ):
        assert column in row
    assert row["explained_variance"] > 0.5 and row["updates"] == state.updates == agent.updates
    assert state.updates == 40 * state.env_steps // (64 * 32)  # epochs x minibatches per rollout


@pytest.mark.slow
def test_reinforce_without_a_baseline_learns_multitask_point_reach():
    cfg = PPOConfig(estimator="reinforce", rollout_steps=50, lr=3e-3, gamma=0.9, value_coef=0.0)
    agent, state, rows, _ = _train_on_point(cfg, total_steps=200_000, stop_at=0.8)
    assert _final_success(agent) >= 0.5  # chance: 0.2
    assert state.updates == state.env_steps // (50 * 32)  # one gradient step per rollout
    assert all(r["value_loss"] == 0.0 and r["clip_fraction"] == 0.0 for r in rows)


class TaskBandit(BatchedEnv):
    """A one-step contextual bandit: the task t in {0, 1, 2} is observed; arm t pays 1, others 0."""

    def __init__(self, num_envs: int, seed: int) -> None:
        self.num_envs, self.device, self.horizon = num_envs, torch.device("cpu"), 1
        self.generator = torch.Generator().manual_seed(seed)
        self.single_action_space = gym.spaces.Discrete(3)

    def _draw(self):
        self.task = torch.randint(3, (self.num_envs,), generator=self.generator)
        return {"observation": torch.zeros(self.num_envs, 1), "task": self.task.clone()}

    def reset(self, seed=None):
        return self._draw()

    def step(self, action):
        success = action == self.task
        final = {"observation": torch.zeros(self.num_envs, 1), "task": self.task.clone()}
        done = torch.ones(self.num_envs, dtype=torch.bool)
        return self._draw(), success.float(), done, ~done, {"is_success": success, "final_obs": final}


@pytest.mark.slow
@pytest.mark.parametrize("estimator", ["reinforce", "ppo"])
def test_categorical_policies_learn_a_contextual_bandit(estimator):
    torch.manual_seed(0)
    env = TaskBandit(16, seed=0)
    cond = make_conditioning(ConditioningConfig(task_encoder="onehot"), 3)
    cfg = PPOConfig(estimator=estimator, rollout_steps=8, lr=1e-2, value_coef=0.0 if estimator == "reinforce" else 0.5)
    agent = PPOAgent(("observation",), 1, env.single_action_space, cfg, conditioning=cond)
    g = torch.Generator().manual_seed(0)
    obs = env.reset()
    for _ in range(30):
        rollout, obs, ended, succeeded = collect_rollout(env, agent, obs, 8, g)
        agent.update(rollout, g)
    assert int(ended) == 128 and rollout.final_value.eq(0).all()  # terminations never bootstrap
    tasks = {"observation": torch.zeros(3, 1), "task": torch.arange(3)}
    assert agent.act(tasks).tolist() == [0, 1, 2]
    probs = torch.softmax(agent.policy_net(torch.zeros(3, 1), cond.encoder(torch.arange(3))), -1)
    assert probs.diagonal().min() > 0.9


@pytest.mark.parametrize("arch, multi_head", [("film", False), ("care", False), ("concat", True)])
def test_every_architecture_runs_an_update(arch, multi_head):
    torch.manual_seed(0)
    env = MultiTaskPointReach(num_envs=5, reward="dense", task_sampling="fixed", seed=0)
    cond = make_conditioning(ConditioningConfig(task_encoder="onehot", architecture=arch, multi_head=multi_head), 5)
    agent = PPOAgent(
        ("observation",), 2, env.single_action_space, PPOConfig(rollout_steps=4, hidden_sizes=(16, 16)), conditioning=cond
    )
    rollout, obs, *_ = collect_rollout(env, agent, env.reset(seed=0), 4)
    before = agent.act(obs)
    metrics = agent.update(rollout)
    assert all(torch.isfinite(v) for v in metrics.values()) and not torch.equal(before, agent.act(obs))


def test_reinforce_without_a_baseline_really_has_none():
    """value_coef = 0: values are zeros at collection, the advantage is the return itself, and the value
    network is never trained (not even through a shared optimiser step)."""
    env = MultiTaskPointReach(num_envs=4, reward="dense", seed=0)
    cond = make_conditioning(ConditioningConfig(task_encoder="onehot"), 5)
    agent = PPOAgent(
        ("observation",),
        2,
        env.single_action_space,
        PPOConfig(estimator="reinforce", value_coef=0.0, rollout_steps=16),
        conditioning=cond,
    )
    before = [p.detach().clone() for p in agent.value_net.parameters()]
    rollout, *_ = collect_rollout(env, agent, env.reset(seed=0), 16, torch.Generator().manual_seed(0))
    assert torch.count_nonzero(rollout.value) == 0 and torch.count_nonzero(rollout.last_value) == 0
    advantages, returns = agent.advantages(rollout)
    assert torch.equal(advantages, returns)
    policy_before = [p.detach().clone() for p in agent.policy_net.parameters()]
    agent.update(rollout, torch.Generator().manual_seed(1))
    assert all(torch.equal(a, b) for a, b in zip(before, agent.value_net.parameters()))
    assert not all(torch.equal(a, b) for a, b in zip(policy_before, agent.policy_net.parameters()))  # it did learn
