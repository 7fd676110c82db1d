import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from agent_batches import bandit_batch, onehot_batch
from taskrl.agents.cem import CEMConfig
from taskrl.agents.qtopt import QTOptAgent, QTOptConfig, StateActionQ
from taskrl.checkpoint import flatten_state, unflatten_state


class Stub(nn.Module):
    """A Q-network given by a formula ``fn(x [B, D], actions [B, N, A]) -> [B, N]`` (actions in [-1, 1])."""

    def __init__(self, fn):
        super().__init__()
        self.fn = fn

    def forward(self, x, action):
        return self.fn(x, action.unsqueeze(1)).squeeze(1)

    def score_actions(self, x, actions):
        return self.fn(x, actions)


def make_agent(low=(-1.0,), high=(1.0,), **cfg):
    torch.manual_seed(0)
    cfg.setdefault("cem", CEMConfig(iterations=4, samples=128, elites=8))
    for name, value in (("target_iterations", 4), ("target_samples", 128), ("target_elites", 8), ("twin", "lagged")):
        cfg.setdefault(name, value)
    return QTOptAgent(
        ("observation",),
        2,
        (torch.tensor(low), torch.tensor(high)),
        QTOptConfig(normalize_inputs=False, hidden_sizes=(8,), **cfg),
    )


def constant(values):
    """Q(s, a) = values[s] for every action (one-hot states)."""
    v = torch.tensor(values)
    return Stub(lambda x, actions: (x @ v).unsqueeze(1).expand(-1, actions.shape[1]))


def test_target_is_the_min_of_both_targets_and_terminated_stops_bootstrapping():
    agent = make_agent(gamma=0.5)
    agent.q_target1, agent.q_target2 = constant([4.0, -1.0]), constant([2.0, 3.0])
    b = onehot_batch([-1.0, -1.0, 0.0], [True, False, False], [False, True, False], [0, 0, 1])
    # terminated: r; truncated still bootstraps: r + gamma * min(4, 2); s'=1: 0 + gamma * min(-1, 3).
    assert agent.bellman_target(b).tolist() == [-1.0, -1.0 + 0.5 * 2.0, 0.5 * -1.0]


def test_target_action_is_the_argmax_of_target1_evaluated_by_both():
    # Q_target1(s, a) peaks at a = 0.4 (s0) / -0.6 (s1) with value 1; Q_target2(s, a) = 10 a.
    # Box [0, 4]: unit action u maps to 2 + 2u, so the argmax is 2.8 / 0.8 in box units.
    peaks = torch.tensor([0.4, -0.6])
    agent = make_agent(low=(0.0,), high=(4.0,), gamma=1.0 - 1e-6)
    agent.q_target1 = Stub(lambda x, a: 1.0 - (a[..., 0] - (x @ peaks).unsqueeze(1)).square())
    agent.q_target2 = Stub(lambda x, a: 10.0 * a[..., 0])
    y, a_star = agent.bellman_target(
        onehot_batch([0.0, 0.0], [False, False], [False, False], [0, 1]),
        generator=torch.Generator().manual_seed(0),
        return_action=True,
    )
    assert a_star[:, 0].tolist() == pytest.approx([2.8, 0.8], abs=0.02)
    # s0: min(1, 10 * 0.4) = 1 (target1); s1: min(1, 10 * -0.6) = -6 (target2).
    assert y.tolist() == pytest.approx([1.0, -6.0], abs=0.1)


def test_warm_started_target_searches_near_the_previous_argmax():
    agent = make_agent(gamma=0.5, cem=CEMConfig(warm_std=0.02, warm_iterations=1))
    agent.q_target1 = agent.q_target2 = Stub(lambda x, a: -(a[..., 0] - 0.3).square())
    b = onehot_batch([0.0], [False], [False], [0])
    _, a_star = agent.bellman_target(
        b, warm_start=torch.tensor([[0.25]]), return_action=True, generator=torch.Generator().manual_seed(0)
    )
    assert a_star.item() == pytest.approx(0.3, abs=0.01)


def test_targets_are_clipped_to_the_return_range_when_asked():
    agent = make_agent(gamma=0.9, clip_target=True)
    agent.q_target1 = agent.q_target2 = constant([50.0, -500.0])
    assert agent.bellman_target(onehot_batch([0.0, -1.0], [False, False], [False, False], [0, 1])).tolist() == pytest.approx(
        [0.0, -10.0]
    )


def test_cross_entropy_mode_uses_probabilities_clips_to_unit_interval_and_log_loss():
    agent = make_agent(gamma=0.9, loss="cross_entropy")
    # logits 0 -> Q = 0.5 (s0); logits 3 / 2 -> Q = sigmoid(2) (s1)
    agent.q_target1, agent.q_target2 = constant([0.0, 3.0]), constant([5.0, 2.0])
    b = onehot_batch([0.0, 1.0, 0.0], [False, False, False], [False, False, False], [0, 1, 1])
    y = agent.bellman_target(b)
    expected = [0.9 * 0.5, 1.0, 0.9 * torch.sigmoid(torch.tensor(2.0)).item()]  # 1 + 0.9 * 0.88 clipped to 1
    assert y.tolist() == pytest.approx(expected, abs=1e-6)
    with torch.no_grad():
        logits = agent.q(agent.inputs(b.obs), agent.box.to_unit(b.action))
    metrics = agent.regress(b, y)
    expected_loss = -(y * F.logsigmoid(logits) + (1 - y) * F.logsigmoid(-logits)).mean()
    assert metrics["loss"].item() == pytest.approx(expected_loss.item(), rel=1e-5)
    expected_q = torch.sigmoid(logits).mean()  # Q = sigmoid(logit) of the batch's own actions
    assert metrics["q_mean"].item() == pytest.approx(expected_q.item(), rel=1e-5)


def test_score_actions_matches_the_plain_forward_pass():
    torch.manual_seed(0)
    net = StateActionQ(5, 3, (16, 16))
    x, actions = torch.randn(4, 5), torch.rand(4, 7, 3) * 2 - 1
    with torch.no_grad():
        plain = net(x.unsqueeze(1).expand(-1, 7, -1).reshape(28, 5), actions.reshape(28, 3)).view(4, 7)
        torch.testing.assert_close(net.score_actions(x, actions), plain)
        torch.testing.assert_close(net.score_actions(x, actions, chunk_rows=10), plain)  # 1 state a chunk
        torch.testing.assert_close(net.score_actions(x, actions, chunk_rows=21), plain)  # 3 + 1 states


def test_target1_is_polyak_averaged_and_target2_lags_it():
    agent = make_agent(tau=0.25, target2_interval=3)
    agent.q_target1, agent.q_target2 = [StateActionQ(2, 1, (8,)) for _ in range(2)]
    agent._target1_params, agent._target2_params = list(agent.q_target1.parameters()), list(agent.q_target2.parameters())
    with torch.no_grad():
        for p in agent._params:
            p.fill_(1.0)
        for p in agent._target1_params + agent._target2_params:
            p.fill_(0.0)
    values = []
    for step in range(1, 7):
        agent.updates = step
        agent.update_targets()
        values.append((agent._target1_params[0].flatten()[0].item(), agent._target2_params[0].flatten()[0].item()))
    t1 = [1 - 0.75**k for k in range(1, 7)]
    assert [v[0] for v in values] == pytest.approx(t1)
    assert [v[1] for v in values] == pytest.approx([0.0, 0.0, t1[2], t1[2], t1[2], t1[5]])


def test_acting_respects_the_bounds_and_explores_uniformly_at_the_requested_rate():
    obs = {"observation": torch.rand(4000, 2)}
    g = torch.Generator().manual_seed(0)
    for prob in (0.0, 0.5, 1.0):
        agent = make_agent(
            low=(-2.0, 0.5), high=(3.0, 1.0), cem=CEMConfig(), random_action_prob_end=prob, random_action_decay_steps=0
        )
        a = agent.act(obs, explore=True, generator=g)
        assert a.shape == (4000, 2)
        assert (a >= torch.tensor([-2.0, 0.5])).all() and (a <= torch.tensor([3.0, 1.0])).all()
    # the agent's own schedule: 0.6 -> 0.2 over 1000 env steps, 0.3 at 750
    agent = make_agent(
        low=(-2.0, 0.5),
        high=(3.0, 1.0),
        cem=CEMConfig(),
        random_action_prob=0.6,
        random_action_prob_end=0.2,
        random_action_decay_steps=1000,
        noise_std=0.0,  # the random share alone
    )
    assert agent.exploration(750) == {"random_action_prob": pytest.approx(0.3)}
    # greedy actions all at the stub's optimum (0.5 in unit space -> 1.75 / 0.875 in the box)
    agent.q = Stub(lambda x, a: -(a - 0.5).square().sum(-1))
    greedy_far = ((agent.act(obs) - torch.tensor([1.75, 0.875])).abs() > torch.tensor([0.5, 0.05])).any(dim=1)
    assert greedy_far.float().mean().item() < 0.01  # greedy: no exploration (CEM's own misses only)
    a = agent.act(obs, explore=True, generator=g, env_steps=750)
    # "far": more than 0.2 (unit space) from the optimum in some dimension; a uniform action is near w.p. 0.2 * 0.2
    far = ((a - torch.tensor([1.75, 0.875])).abs() > torch.tensor([0.5, 0.05])).any(dim=1).float().mean().item()
    assert far == pytest.approx(0.3 * (1 - 0.2 * 0.2), abs=0.025)
    single = agent.act({"observation": np.array([1.0, 0.0], dtype=np.float32)})
    assert isinstance(single, np.ndarray) and single.shape == (2,)


@pytest.mark.slow
def test_qtopt_learns_the_best_action_of_a_continuous_bandit():
    # One-step bandit, two states with different best actions; reward in [0, 1] (log loss).
    best = torch.tensor([-0.5, 0.6])
    torch.manual_seed(0)
    agent = QTOptAgent(
        ("observation",),
        2,
        (torch.tensor([-1.0]), torch.tensor([1.0])),
        QTOptConfig(lr=3e-3, hidden_sizes=(64, 64), loss="cross_entropy", normalize_inputs=False),
    )
    g = torch.Generator().manual_seed(0)
    for _ in range(300):
        agent.update(bandit_batch(best, g, reward=lambda gap: torch.exp(-4.0 * gap.square())), generator=g)
    greedy = agent.act({"observation": torch.eye(2)}, generator=g)
    assert greedy[:, 0].tolist() == pytest.approx(best.tolist(), abs=0.1)


def test_state_dict_round_trips_through_the_checkpoint_format():
    agent = make_agent()
    b = onehot_batch([0.0, -1.0], [False, True], [False, False], [0, 1])
    agent.update(b)
    tensors, skeleton = flatten_state(agent.state_dict())
    other = make_agent()
    other.load_state_dict(unflatten_state(tensors, skeleton))
    assert other.updates == 1
    x, a = torch.eye(2), torch.zeros(2, 1)
    for name in ("q", "q_target1", "q_target2"):
        torch.testing.assert_close(getattr(other, name)(x, a), getattr(agent, name)(x, a))


def test_independent_twins_are_two_networks_both_regressed_onto_one_target_with_their_own_polyak_targets():
    agent = make_agent(twin="independent", tau=0.5, lr=1e-2, loss="mse")
    x, a = torch.eye(2), torch.zeros(2, 1)
    with torch.no_grad():
        assert not torch.allclose(agent.q(x, a), agent.q2(x, a))  # own initialisations
        torch.testing.assert_close(agent.q_target2(x, a), agent.q2(x, a))  # target2 starts as q2, not q
    before = [p.clone() for p in agent.q2.parameters()]
    target2_before = [p.clone() for p in agent.q_target2.parameters()]
    b = onehot_batch([-1.0, 0.0], [True, True], [False, False], [0, 1])  # terminated: y = r
    y = torch.tensor([-1.0, 0.0])
    for _ in range(300):
        agent.regress(b, y)
    with torch.no_grad():
        # both twins learnt y: the second one is in the loss
        torch.testing.assert_close(agent.q(x, a), y, atol=0.05, rtol=0)
        torch.testing.assert_close(agent.q2(x, a), y, atol=0.05, rtol=0)
        # target2 follows q2 by Polyak averaging (tau = 0.5), never by copying target1
        for p, p0, t, t0 in zip(agent.q2.parameters(), before, agent.q_target2.parameters(), target2_before):
            assert not torch.equal(p, p0) and not torch.equal(t, t0)
        torch.testing.assert_close(agent.q_target2(x, a), agent.q2(x, a), atol=1e-3, rtol=0)
        assert not torch.allclose(agent.q_target2(x, torch.ones(2, 1)), agent.q_target1(x, torch.ones(2, 1)))
    # checkpoints carry the second twin
    tensors, skeleton = flatten_state(agent.state_dict())
    other = make_agent(twin="independent")
    other.load_state_dict(unflatten_state(tensors, skeleton))
    with torch.no_grad():
        torch.testing.assert_close(other.q2(x, a), agent.q2(x, a))


def test_the_first_update_refuses_rewards_outside_the_range_the_bound_on_q_assumes():
    from taskrl.errors import ConfigError

    positive = onehot_batch([1.0, 0.0], [True, True], [False, False], [0, 1])
    with pytest.raises(ConfigError, match="clip_target"):
        make_agent(clip_target=True).update(positive)
    negative = onehot_batch([-1.0, 0.0], [True, True], [False, False], [0, 1])
    with pytest.raises(ConfigError, match="loss"):
        make_agent(loss="cross_entropy").update(negative)
    make_agent(clip_target=True).update(negative)  # in range
    make_agent().update(positive)  # unbounded Huber takes any reward


def test_an_initial_cem_mean_of_the_wrong_length_is_refused_when_the_agent_is_made():
    from taskrl.errors import ConfigError

    with pytest.raises(ConfigError, match="init_mean"):
        make_agent(cem=CEMConfig(init_mean=(0.0, -1.0, 0.0)))


def test_the_bellman_maximum_searches_the_whole_box_whatever_prior_the_acting_search_has():
    """Acting starts narrowly at 0.9 (``cem.init_mean``, ``init_std`` 0.05) and stays there; the target's search over the
    same Q finds its peak at -0.8. Mutation: the target searching with the acting prior -> its argmax stays near 0.9."""
    prior = CEMConfig(iterations=1, samples=64, elites=4, init_std=0.05, init_mean=(0.9,), truncate=True)
    agent = make_agent(cem=prior, target_iterations=3, target_samples=64, target_elites=6)
    agent.q = agent.q_target1 = agent.q_target2 = Stub(lambda x, a: -(a[..., 0] + 0.8).square())
    b = onehot_batch([0.0], [False], [False], [0])
    acted, _ = agent.argmax(agent.q, b.obs["observation"], generator=torch.Generator().manual_seed(0))
    assert acted.item() > 0.7
    _, a_star = agent.bellman_target(b, return_action=True, generator=torch.Generator().manual_seed(0))
    assert a_star.item() == pytest.approx(-0.8, abs=0.05)


def test_the_bellman_maximum_searches_with_its_own_smaller_cem():
    """The target's CEM scores ``target_samples`` candidates per row in ``target_iterations`` rounds; acting scores the
    acting ``cem``'s. Mutation: the target searching with the acting CEM's sizes fails."""
    agent = make_agent(cem=CEMConfig(iterations=2, samples=64, elites=6), target_samples=16, target_iterations=1, target_elites=2)
    shapes = []
    agent.q_target1 = Stub(lambda x, a: shapes.append(tuple(a.shape)) or -a[..., 0].square())
    agent.q_target2 = constant([0.0, 0.0])
    agent.bellman_target(onehot_batch([0.0, 0.0, 0.0], [False] * 3, [False] * 3, [0, 1, 0]))
    assert shapes == [(3, 16, 1)]
    agent.q = agent.q_target1
    shapes.clear()
    agent.act({"observation": torch.eye(2)})
    assert shapes == [(2, 64, 1), (2, 64, 1)]
    with pytest.raises(Exception, match="target_elites"):
        QTOptConfig(target_samples=8, target_elites=9).validate()


def test_each_update_reports_the_bound_share_the_batch_reward_the_q_spread_and_how_often_the_twin_minimum_clips():
    agent = make_agent(twin="lagged")
    # stored actions: 2 of 4 components on a bound (the box is [-1, 1]); rewards: mean -0.25
    batch = onehot_batch(
        [0.0, -1.0, 0.0, 0.0], [False] * 4, [False] * 4, [0, 1, 0, 1], action=torch.tensor([[1.0], [-1.0], [0.3], [0.0]])
    )
    # target2 below target1 in the rows of state 1 (half the rows); Q_target1 varies with the action in state 0 only
    agent.q_target1 = Stub(lambda x, a: x[:, :1] * a[..., 0] + 0.0 * x[:, 1:])
    agent.q_target2 = Stub(lambda x, a: x[:, :1] * a[..., 0] - x[:, 1:] * torch.ones_like(a[..., 0]))
    metrics = agent.update(batch)
    assert metrics["action_on_bound"].item() == pytest.approx(0.5)
    assert metrics["batch_reward"].item() == pytest.approx(-0.25)
    assert metrics["twin_clip_rate"].item() == pytest.approx(0.5)
    # state 0: Q = a over candidates spread across the box (std about 0.5); state 1: Q constant (std 0)
    assert 0.15 < metrics["q_spread"].item() < 0.4


class _RecordingEnv:
    """Four copies of a one-hot state for ``horizon`` steps; keeps every action it is given."""

    num_envs, device, horizon = 4, torch.device("cpu"), 3

    def __init__(self) -> None:
        self.actions: list[torch.Tensor] = []

    def reset(self, seed: int) -> dict:
        return {"observation": torch.eye(2)[[0, 1, 0, 1]]}

    def step(self, action: torch.Tensor):
        self.actions.append(action.clone())
        none = torch.zeros(self.num_envs, dtype=torch.bool)
        return self.reset(0), torch.zeros(self.num_envs), none, none, {"is_success": none}


def test_an_evaluation_draws_its_cem_candidates_from_its_own_seed():
    """The same checkpoint scores the same at every evaluation with one seed: the greedy CEM's candidate actions come
    from the evaluation's own generator, seeded with its seed, whatever else drew from torch's global one. Mutation:
    `ActingPolicy` not passing its generator (CEM drawing from the global one) fails."""
    from taskrl.training.evaluation import ActingPolicy, evaluate

    agent = make_agent(cem=CEMConfig(iterations=1, samples=4, elites=1))
    policy, first, second, other = ActingPolicy(agent), _RecordingEnv(), _RecordingEnv(), _RecordingEnv()
    evaluate(policy, first, seed=7)
    torch.rand(100)  # the global generator moves on between evaluations
    evaluate(policy, second, seed=7)
    evaluate(policy, other, seed=8)
    assert all(torch.equal(a, b) for a, b in zip(first.actions, second.actions, strict=True))
    assert not all(torch.equal(a, b) for a, b in zip(first.actions, other.actions, strict=True))


def test_an_evaluation_acts_with_the_cem_search_it_is_given(tmp_path, monkeypatch):
    """``taskrl eval RUN --cem samples=N ...`` (``evaluate_run(cem=...)``) acts with that search instead of the run's;
    a setting CEM lacks, or a value it refuses, is one line naming it. Mutation: the changes not applied fails."""
    import json

    from helpers import cli, small_run
    from taskrl import loading
    from taskrl.agents import cem as cem_module
    from taskrl.errors import ConfigError

    small_run("pointreach-qtopt-her", tmp_path / "run", total_steps=64, learning_starts=32, eval_interval=64, eval_episodes=2)
    counts = []
    maximize = cem_module.maximize
    monkeypatch.setattr(
        cem_module, "maximize", lambda *a, **k: counts.append((a[4], tuple(a[5]), a[6])) or maximize(*a, **k)
    )  # (iterations, samples, elites)
    result = loading.evaluate_run(tmp_path / "run", episodes=2, cem={"samples": 7, "iterations": 3, "elites": 2})
    assert counts and set(counts) == {(3, (7, 7, 7), 2)}
    assert result["cem"]["samples"] == 7 and result["cem"]["iterations"] == 3
    counts.clear()
    loading.evaluate_run(tmp_path / "run", episodes=2)
    assert set(counts) == {(2, (64, 64), 6)}  # the run's own search
    with pytest.raises(ConfigError, match="cem.elites"):
        loading.evaluate_run(tmp_path / "run", episodes=2, cem={"samples": 4, "elites": 5})
    done = cli("eval", str(tmp_path / "run"), "--episodes", "2", "--cem", "samples=9", "--json")
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["cem"]["samples"] == 9
    done = cli("eval", str(tmp_path / "run"), "--episodes", "2", "--cem", "sample=9")
    assert done.returncode == 2 and "--cem takes NAME=VALUE" in done.stderr and "samples" in done.stderr
