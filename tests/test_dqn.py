import numpy as np
import pytest
import torch

from agent_batches import onehot_batch
from taskrl.agents.dqn import DQNAgent, DQNConfig
from taskrl.replay.batch import Batch


def make_agent(**cfg):
    torch.manual_seed(0)
    return DQNAgent(("observation",), 2, 3, DQNConfig(normalize_inputs=False, **cfg))


def set_q(net, values_per_state):
    """Make a Q-network output fixed values: input one-hot state (2 states) -> 3 action values."""
    layer_in, layer_out = net.body[0], net.body[-1]
    with torch.no_grad():
        for p in net.parameters():
            p.zero_()
        layer_in.weight[:2, :2] = torch.eye(2)  # hidden = relu(onehot)
        layer_out.weight[:, :2] = torch.tensor(values_per_state, dtype=torch.float32).T


def test_bellman_target_terminated_stops_and_truncated_bootstraps():
    agent = make_agent(gamma=0.5, double_q=False, clip_target=False, hidden_sizes=(4,))
    set_q(agent.q_target, [[1.0, 4.0, 2.0], [-2.0, -1.0, -3.0]])
    b = onehot_batch([-1.0, -1.0, 0.0], [True, False, False], [False, True, False], [0, 0, 1])
    # terminated: r; truncated: r + gamma * max Q_target(s'); plain: r + gamma * max.
    assert agent.bellman_target(b).tolist() == [-1.0, -1.0 + 0.5 * 4.0, 0.0 + 0.5 * -1.0]


def test_double_q_selects_with_online_and_evaluates_with_target():
    agent = make_agent(gamma=0.5, double_q=True, clip_target=False, hidden_sizes=(4,))
    set_q(agent.q, [[0.0, 0.0, 9.0], [9.0, 0.0, 0.0]])  # online argmax: 2 in s0, 0 in s1
    set_q(agent.q_target, [[1.0, 4.0, 2.0], [-2.0, -1.0, -3.0]])
    b = onehot_batch([0.0, 0.0], [False, False], [False, False], [0, 1])
    assert agent.bellman_target(b).tolist() == [0.5 * 2.0, 0.5 * -2.0]


def test_targets_are_clipped_to_the_return_range():
    agent = make_agent(gamma=0.9, double_q=False, clip_target=True, hidden_sizes=(4,))
    set_q(agent.q_target, [[50.0, 0.0, 0.0], [-500.0, -500.0, -500.0]])
    b = onehot_batch([0.0, -1.0], [False, False], [False, False], [0, 1])
    assert agent.bellman_target(b).tolist() == pytest.approx([0.0, -10.0])


def test_polyak_and_hard_target_updates():
    agent = make_agent(tau=0.25, hidden_sizes=(4,))
    with torch.no_grad():
        for p in agent.q.parameters():
            p.fill_(1.0)
        for p in agent.q_target.parameters():
            p.fill_(0.0)
    agent.update_target()
    assert all(torch.allclose(p, torch.full_like(p, 0.25)) for p in agent.q_target.parameters())
    agent.config.tau = 1.0
    agent.update_target()
    assert all(torch.equal(p, torch.ones_like(p)) for p in agent.q_target.parameters())


def chain_mdp(n_states=4, gamma=0.9):
    """Deterministic chain: action 1 moves right, action 0 stays; reaching the last state gives 0
    and terminates; every other step costs -1. Q* in closed form by value iteration."""
    v = np.zeros(n_states)
    for _ in range(200):
        q = np.zeros((n_states, 2))
        for s in range(n_states - 1):
            for a in range(2):
                s2 = min(s + a, n_states - 1)
                done = s2 == n_states - 1
                q[s, a] = (0.0 if done else -1.0) + (0.0 if done else gamma * v[s2])
        v = q.max(1)
    return q[: n_states - 1]


@pytest.mark.slow
def test_dqn_converges_to_q_star_of_a_tiny_mdp():
    n, gamma = 4, 0.9
    q_star = chain_mdp(n, gamma)
    torch.manual_seed(0)
    agent = DQNAgent(
        ("observation",),
        n,
        2,
        DQNConfig(
            lr=3e-3,
            gamma=gamma,
            hidden_sizes=(64,),
            loss="mse",
            tau=1.0,
            target_update_interval=50,
            clip_target=False,
            normalize_inputs=False,
        ),
    )
    eye = torch.eye(n)
    s = torch.arange(n - 1).repeat_interleave(2)
    a = torch.tensor([0, 1] * (n - 1))
    s2 = torch.clamp(s + a, max=n - 1)
    done = s2 == n - 1
    data = Batch(
        obs={"observation": eye[s]},
        action=a,
        reward=torch.where(done, 0.0, -1.0),
        next_obs={"observation": eye[s2]},
        terminated=done,
        truncated=torch.zeros_like(done),
        episode=torch.zeros_like(s),
        step=torch.zeros_like(s),
    )
    for _ in range(3000):
        agent.update(data)
    with torch.no_grad():
        q = agent.q(agent.inputs({"observation": eye[: n - 1]})).numpy()
    np.testing.assert_allclose(q, q_star, atol=0.05)
    assert (q.argmax(1) == 1).all()


def test_epsilon_greedy_explores_at_the_requested_rate():
    agent = make_agent(hidden_sizes=(4,), epsilon_start=0.6, epsilon_end=0.0, epsilon_decay_steps=1000)
    set_q(agent.q, [[0.0, 0.0, 9.0], [0.0, 0.0, 9.0]])
    obs = {"observation": torch.nn.functional.one_hot(torch.zeros(30_000, dtype=torch.long), 2).float()}
    g = torch.Generator().manual_seed(0)
    assert agent.exploration(500) == {"epsilon": pytest.approx(0.3)}  # the agent's own schedule, halfway
    actions = agent.act(obs, explore=True, generator=g, env_steps=500)
    non_greedy = (actions != 2).float().mean().item()
    assert abs(non_greedy - 0.3 * 2 / 3) < 0.01
    assert (agent.act(obs) == 2).all()


def test_act_accepts_a_single_numpy_observation():
    agent = make_agent(hidden_sizes=(4,))
    set_q(agent.q, [[0.0, 7.0, 0.0], [0.0, 0.0, 0.0]])
    assert agent.act({"observation": np.array([1.0, 0.0], dtype=np.float32)}) == 1
