import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from agent_batches import bandit_batch
from taskrl.agents.td3 import TD3Agent, TD3Config
from taskrl.checkpoint import flatten_state, unflatten_state
from taskrl.replay.batch import Batch


class LinearQ(nn.Module):
    """Q(s, a) = base[s] + slope * a (one-hot states, 1-D actions)."""

    def __init__(self, base, slope):
        super().__init__()
        self.base, self.slope = torch.tensor(base), slope

    def forward(self, x, action):
        return x @ self.base + self.slope * action[:, 0]


class ConstActor(nn.Module):
    def __init__(self, value):
        super().__init__()
        self.value = value

    def forward(self, x):
        return torch.full((x.shape[0], 1), self.value)


def make_agent(low=(-1.0,), high=(1.0,), **cfg):
    torch.manual_seed(0)
    cfg.setdefault("hidden_sizes", (16,))
    return TD3Agent(("observation",), 2, (torch.tensor(low), torch.tensor(high)), TD3Config(normalize_inputs=False, **cfg))


def batch(reward, terminated, truncated, next_state):
    n = len(reward)
    onehot = F.one_hot(torch.tensor(next_state), 2).float()
    return Batch(
        obs={"observation": onehot},
        action=torch.zeros(n, 1),
        reward=torch.tensor(reward),
        next_obs={"observation": onehot},
        terminated=torch.tensor(terminated),
        truncated=torch.tensor(truncated),
        episode=torch.zeros(n, dtype=torch.long),
        step=torch.zeros(n, dtype=torch.long),
    )


def test_bellman_target_on_hand_numbers_without_smoothing():
    agent = make_agent(gamma=0.5, target_noise=0.0)
    agent.actor_target = ConstActor(0.5)
    agent.critics_target = nn.ModuleList([LinearQ([4.0, -1.0], 2.0), LinearQ([3.0, 5.0], 0.0)])
    b = batch([-1.0, -1.0, 0.0], [True, False, False], [False, True, False], [0, 0, 1])
    # Q1 = base + 2 * 0.5: s0 -> 5, s1 -> 0; Q2: s0 -> 3, s1 -> 5
    assert agent.bellman_target(b).tolist() == pytest.approx([-1.0, -1.0 + 0.5 * 3.0, 0.5 * 0.0])


def test_target_smoothing_noise_is_clipped_and_actions_stay_in_range():
    agent = make_agent(gamma=1.0 - 1e-6, target_noise=10.0, target_noise_clip=0.3)
    agent.actor_target = ConstActor(0.9)
    agent.critics_target = nn.ModuleList([LinearQ([0.0, 0.0], 1.0), LinearQ([0.0, 0.0], 1.0)])
    y = agent.bellman_target(batch([0.0] * 2000, [False] * 2000, [False] * 2000, [0] * 2000), torch.Generator().manual_seed(0))
    # next action = clip(0.9 + clip(noise, -0.3, 0.3), -1, 1) in {0.6, 1.0} almost surely, never outside [0.6, 1]
    assert y.min().item() == pytest.approx(0.6, abs=1e-4) and y.max().item() == pytest.approx(1.0, abs=1e-4)


def test_actor_and_targets_update_only_every_policy_delay_steps():
    agent = make_agent(policy_delay=3)
    g = torch.Generator().manual_seed(0)
    before = [p.clone() for p in agent.actor.parameters()]
    b = batch([0.0, -1.0], [False, True], [False, False], [0, 1])
    agent.update(b, g)
    agent.update(b, g)
    assert all(torch.equal(p, q) for p, q in zip(agent.actor.parameters(), before))
    assert all(torch.equal(p, q) for p, q in zip(agent.actor_target.parameters(), before))
    metrics = agent.update(b, g)
    assert not all(torch.equal(p, q) for p, q in zip(agent.actor.parameters(), before))
    assert set(metrics) == {"critic_loss", "actor_loss", "q_mean"}


def test_td3_learns_the_best_action_of_a_continuous_bandit():
    best = torch.tensor([-0.5, 0.6])
    torch.manual_seed(0)
    agent = TD3Agent(
        ("observation",),
        2,
        (torch.tensor([-1.0]), torch.tensor([1.0])),
        TD3Config(lr=3e-3, hidden_sizes=(64, 64), normalize_inputs=False),
    )
    g = torch.Generator().manual_seed(0)
    for _ in range(400):
        agent.update(bandit_batch(best, g), generator=g)
    assert agent.act({"observation": torch.eye(2)})[:, 0].tolist() == pytest.approx(best.tolist(), abs=0.1)


def test_acting_respects_bounds_and_round_trips_state():
    agent = make_agent(low=(-2.0, 0.5), high=(3.0, 1.0), noise_std=0.5)
    obs = {"observation": torch.randn(500, 2) * 3}
    for explore in (False, True):
        a = agent.act(obs, explore=explore, generator=torch.Generator().manual_seed(0))
        assert (a >= torch.tensor([-2.0, 0.5])).all() and (a <= torch.tensor([3.0, 1.0])).all()
    single = agent.act({"observation": np.array([1.0, 0.0], dtype=np.float32)})
    assert isinstance(single, np.ndarray) and single.shape == (2,)
    with torch.no_grad():
        for p in agent.actor.parameters():
            p.add_(0.1)
    tensors, skeleton = flatten_state(agent.state_dict())
    other = make_agent(low=(-2.0, 0.5), high=(3.0, 1.0))
    other.load_state_dict(unflatten_state(tensors, skeleton))
    torch.testing.assert_close(other.act(obs), agent.act(obs))
    assert not torch.allclose(make_agent(low=(-2.0, 0.5), high=(3.0, 1.0)).act(obs), agent.act(obs))


def test_hindsight_paper_exploration_mixes_gaussian_noise_and_random_actions():
    from taskrl.agents.parts import explore_in_box

    g = torch.Generator().manual_seed(0)
    greedy = torch.full((20_000, 2), 0.5)
    noisy = explore_in_box(greedy, 0.2, 0.0, g)
    assert noisy.abs().max() <= 1.0 and abs((noisy - 0.5).std().item() - 0.2) < 0.01
    mixed = explore_in_box(greedy, 0.0, 0.3, g)
    random_rows = (mixed != 0.5).any(1)
    assert abs(random_rows.float().mean().item() - 0.3) < 0.02
    assert mixed[random_rows].min() < -0.9 and mixed[random_rows].max() > 0.9  # uniform over the box
    assert torch.equal(explore_in_box(greedy, 0.0, 0.0, g), greedy)
