import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from agent_batches import bandit_batch, onehot_batch
from taskrl.agents.sac import SACAgent, SACConfig, SquashedGaussianActor, squashed_gaussian_log_prob
from taskrl.checkpoint import flatten_state, unflatten_state
from taskrl.replay.batch import Batch


class ConstQ(nn.Module):
    """Q(s, a) = values[s] for every action (one-hot states)."""

    def __init__(self, values):
        super().__init__()
        self.values = torch.tensor(values)

    def forward(self, x, action, context=None, task=None):
        return x @ self.values


class FixedActor:
    """Stands in for the actor in the target: a' = 0 and log pi(a'|s') = log_probs[s']."""

    def __init__(self, log_probs):
        self.log_probs = torch.tensor(log_probs)

    def sample(self, x, generator=None, context=None, task=None):
        return torch.zeros(x.shape[0], 1), x @ self.log_probs


def make_agent(low=(-1.0,), high=(1.0,), **cfg):
    torch.manual_seed(0)
    cfg.setdefault("hidden_sizes", (16,))
    return SACAgent(("observation",), 2, (torch.tensor(low), torch.tensor(high)), SACConfig(normalize_inputs=False, **cfg))


def test_squashed_log_prob_matches_a_numerical_change_of_variables_in_one_dimension():
    mean, log_std = torch.tensor([0.3], dtype=torch.float64), torch.tensor([math.log(0.8)], dtype=torch.float64)
    a = torch.linspace(-0.999, 0.999, 4001, dtype=torch.float64)
    u = torch.atanh(a)
    h = 1e-6
    du_da = (torch.atanh(a + h) - torch.atanh(a - h)) / (2 * h)  # numerical |du/da|
    gaussian = torch.distributions.Normal(mean, log_std.exp()).log_prob(u)
    expected = gaussian + torch.log(du_da)  # p_a(a) = p_u(u(a)) |du/da|
    got = squashed_gaussian_log_prob(u.unsqueeze(1), mean, log_std)
    torch.testing.assert_close(got, expected, rtol=1e-6, atol=1e-6)
    # and it is a density on (-1, 1): integrates to ~1 (a little mass lies beyond +-0.999)
    assert torch.trapezoid(got.exp(), a).item() == pytest.approx(1.0, abs=2e-3)


def test_squashed_log_prob_matches_the_jacobian_determinant_in_several_dimensions():
    torch.manual_seed(0)
    mean, log_std = torch.randn(3, dtype=torch.float64), torch.randn(3, dtype=torch.float64) * 0.3
    for _ in range(5):
        u = torch.randn(3, dtype=torch.float64) * 1.5
        jac = torch.autograd.functional.jacobian(torch.tanh, u)  # da/du, 3 x 3
        expected = torch.distributions.Normal(mean, log_std.exp()).log_prob(u).sum() - torch.linalg.slogdet(jac).logabsdet
        assert squashed_gaussian_log_prob(u, mean, log_std).item() == pytest.approx(expected.item(), abs=1e-9)
    # saturated tanh: still finite in float32
    big = torch.tensor([30.0, -30.0])
    assert torch.isfinite(squashed_gaussian_log_prob(big, torch.zeros(2), torch.zeros(2)))


def test_actor_sample_is_squashed_and_its_log_prob_is_consistent():
    torch.manual_seed(0)
    actor = SquashedGaussianActor(4, 2, (16,), -5.0, 2.0)
    x = torch.randn(64, 4)
    a, log_prob = actor.sample(x, torch.Generator().manual_seed(0))
    assert a.shape == (64, 2) and log_prob.shape == (64,)
    assert (a.abs() < 1).all()
    mean, log_std = actor(x)
    assert (log_std >= -5.0).all() and (log_std <= 2.0).all()
    torch.testing.assert_close(
        log_prob,
        squashed_gaussian_log_prob(torch.atanh(a.double()), mean.double(), log_std.double()).float(),
        rtol=1e-3,
        atol=1e-3,
    )


def test_bellman_target_on_hand_numbers():
    agent = make_agent(gamma=0.5, init_alpha=0.2)
    agent.actor = FixedActor([-1.0, 2.0])
    agent.critics_target = nn.ModuleList([ConstQ([4.0, -1.0]), ConstQ([3.0, 5.0])])
    b = onehot_batch([-1.0, -1.0, 0.0], [True, False, False], [False, True, False], [0, 0, 1])
    # terminated: r; truncated bootstraps: r + 0.5 * (min(4, 3) - 0.2 * -1); s'=1: 0.5 * (min(-1, 5) - 0.2 * 2)
    assert agent.bellman_target(b).tolist() == pytest.approx([-1.0, -1.0 + 0.5 * 3.2, 0.5 * -1.4])


def test_bellman_target_clipping():
    agent = make_agent(gamma=0.9, init_alpha=1.0, clip_target=True)
    agent.actor = FixedActor([0.0, 0.0])
    agent.critics_target = nn.ModuleList([ConstQ([50.0, -500.0]), ConstQ([50.0, -500.0])])
    assert agent.bellman_target(onehot_batch([0.0, -1.0], [False, False], [False, False], [0, 1])).tolist() == pytest.approx(
        [0.0, -10.0]
    )


def random_batch(g, n=64):
    s = torch.randint(0, 2, (n,), generator=g)
    onehot = F.one_hot(s, 2).float()
    done = torch.ones(n, dtype=torch.bool)
    return Batch(
        obs={"observation": onehot},
        action=torch.rand(n, 1, generator=g) * 2 - 1,
        reward=torch.zeros(n),
        next_obs={"observation": onehot},
        terminated=done,
        truncated=~done,
        episode=s,
        step=s,
    )


@pytest.mark.parametrize("target_per_dim, direction", [(5.0, 1), (-20.0, -1)])
def test_temperature_moves_toward_the_target_entropy(target_per_dim, direction):
    # An entropy of +5 per dimension is unreachable on [-1, 1] (at most log 2): alpha must grow.
    # -20 is far below any policy's entropy here: alpha must shrink.
    agent = make_agent(lr=1e-2, init_alpha=1.0, target_entropy_per_dim=target_per_dim)
    g = torch.Generator().manual_seed(0)
    for _ in range(30):
        metrics = agent.update(random_batch(g), generator=g)
    assert (agent.alpha.item() - 1.0) * direction > 0.2
    assert set(metrics) == {"critic_loss", "actor_loss", "alpha", "entropy", "q_mean", "action_on_bound"}
    assert all(isinstance(v, torch.Tensor) and v.dim() == 0 and not v.requires_grad for v in metrics.values())


def test_fixed_temperature_stays_put():
    agent = make_agent(init_alpha=0.3, learn_alpha=False)
    g = torch.Generator().manual_seed(0)
    for _ in range(5):
        agent.update(random_batch(g), generator=g)
    assert agent.alpha.item() == pytest.approx(0.3)


@pytest.mark.slow
def test_sac_learns_the_best_action_of_a_continuous_bandit():
    best = torch.tensor([-0.5, 0.6])
    torch.manual_seed(0)
    agent = SACAgent(
        ("observation",),
        2,
        (torch.tensor([-1.0]), torch.tensor([1.0])),
        SACConfig(lr=3e-3, hidden_sizes=(64, 64), init_alpha=0.05, normalize_inputs=False),
    )
    g = torch.Generator().manual_seed(0)
    for _ in range(400):
        agent.update(bandit_batch(best, g), generator=g)
    greedy = agent.act({"observation": torch.eye(2)})
    assert greedy[:, 0].tolist() == pytest.approx(best.tolist(), abs=0.1)


def test_acting_respects_bounds_is_deterministic_without_exploration_and_takes_numpy():
    agent = make_agent(low=(-2.0, 0.5), high=(3.0, 1.0))
    obs = {"observation": torch.randn(500, 2) * 3}
    g = torch.Generator().manual_seed(0)
    greedy = agent.act(obs)
    torch.testing.assert_close(agent.act(obs), greedy)
    sampled = agent.act(obs, explore=True, generator=g)
    for a in (greedy, sampled):
        assert a.shape == (500, 2)
        assert (a >= torch.tensor([-2.0, 0.5])).all() and (a <= torch.tensor([3.0, 1.0])).all()
    assert not torch.allclose(sampled, greedy)
    single = agent.act({"observation": np.array([1.0, 0.0], dtype=np.float32)})
    assert isinstance(single, np.ndarray) and single.shape == (2,)


def test_state_dict_round_trips_through_the_checkpoint_format():
    agent = make_agent()
    g = torch.Generator().manual_seed(0)
    agent.update(random_batch(g), generator=g)
    tensors, skeleton = flatten_state(agent.state_dict())
    other = make_agent(init_alpha=0.5)
    other.load_state_dict(unflatten_state(tensors, skeleton))
    assert other.updates == 1 and other.alpha.item() == pytest.approx(agent.alpha.item())
    x = torch.eye(2)
    torch.testing.assert_close(other.act({"observation": x}), agent.act({"observation": x}))
    for mine, theirs in zip(agent.critics_target, other.critics_target):
        torch.testing.assert_close(theirs(x, torch.zeros(2, 1)), mine(x, torch.zeros(2, 1)))


def test_the_three_losses_match_a_hand_computation():
    """J_Q, J_pi and the temperature's gradient on a hand-made batch, computed here independently
    (torch.distributions for the squashed Gaussian's density, the same two noise draws as the
    update: a' for the target, then a~ for the actor); lr is tiny, so the networks do not move
    within the update."""
    from torch.distributions import Normal

    agent = SACAgent(
        ("observation",),
        2,
        (torch.tensor([-1.0]), torch.tensor([1.0])),
        SACConfig(lr=1e-12, gamma=0.9, init_alpha=0.5, hidden_sizes=(8,), normalize_inputs=False),
    )
    s = torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5]])
    s2 = torch.tensor([[0.0, 1.0], [1.0, 0.0], [0.2, 0.8]])
    a, r = torch.tensor([[0.3], [-0.7], [0.1]]), torch.tensor([1.0, -1.0, 0.5])
    term = torch.tensor([False, True, False])
    batch = Batch(
        obs={"observation": s},
        action=a,
        reward=r,
        next_obs={"observation": s2},
        terminated=term,
        truncated=torch.zeros(3, dtype=torch.bool),
        episode=torch.zeros(3, dtype=torch.long),
        step=torch.zeros(3, dtype=torch.long),
    )

    def sample(x, eps):
        mean, log_std = agent.actor(x)
        u = mean + log_std.exp() * eps
        log_p = Normal(mean, log_std.exp()).log_prob(u).sum(-1) - torch.log(1 - torch.tanh(u).square() + 1e-12).sum(-1)
        return torch.tanh(u), log_p

    g = torch.Generator().manual_seed(7)
    eps_target, eps_actor = torch.randn(3, 1, generator=g), torch.randn(3, 1, generator=g)
    with torch.no_grad():
        next_a, next_logp = sample(s2, eps_target)
        next_q = torch.minimum(*(q(s2, next_a) for q in agent.critics_target))
        y = r + 0.9 * (~term).float() * (next_q - 0.5 * next_logp)
        q1, q2 = (q(s, a) for q in agent.critics)
        critic_loss = 0.5 * (((q1 - y) ** 2).mean() + ((q2 - y) ** 2).mean())
        new_a, logp = sample(s, eps_actor)
        actor_loss = (0.5 * logp - torch.minimum(*(q(s, new_a) for q in agent.critics))).mean()
        alpha_grad = -(logp + agent.target_entropy).mean()  # d/d log_alpha of -log_alpha (log pi + target)

    m = agent.update(batch, generator=torch.Generator().manual_seed(7))
    assert m["critic_loss"].item() == pytest.approx(critic_loss.item(), rel=1e-4)
    assert m["actor_loss"].item() == pytest.approx(actor_loss.item(), rel=1e-4)
    assert m["entropy"].item() == pytest.approx(-logp.mean().item(), rel=1e-4)
    assert agent.log_alpha.grad.item() == pytest.approx(alpha_grad.item(), rel=1e-4)
