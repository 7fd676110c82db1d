"""Q-learning and fitted Q-iteration reach Q* on small MDPs."""

import numpy as np
import pytest
from tabular_helpers import random_mdp

from taskrl.tabular import (
    FiniteMDP,
    Transitions,
    evaluate_policy,
    fitted_q_iteration,
    grid_world,
    mdp_from_gymnasium,
    q_learning,
    sample_transitions,
    value_iteration,
)


def q_star(mdp):
    return value_iteration(mdp, tol=1e-13).q_values


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_q_learning_converges_to_q_star_on_random_mdps(seed):
    mdp = random_mdp(seed, S=5, A=2, gamma=0.7, successors=3, n_terminal=1, sas_rewards=True)
    live = ~mdp.terminal
    short = q_learning(mdp, episodes=500, epsilon=1.0, max_steps=30, seed=seed)
    long = q_learning(mdp, episodes=20_000, epsilon=1.0, max_steps=30, seed=seed)
    err_short = np.abs(short.q_values - q_star(mdp))[live].max()
    err_long = np.abs(long.q_values - q_star(mdp))[live].max()
    assert err_long < 0.05  # rewards in [-1, 1], |Q*| up to ~3
    assert err_long < err_short
    assert long.visits[live].min() > 1000 and long.steps == long.visits.sum()


def test_q_learning_epsilon_greedy_finds_an_optimal_grid_policy():
    g = grid_world(layout=["...", "..H", "..G"], slip=0.2, gamma=0.9)
    mdp = FiniteMDP(g.P, g.R, g.gamma, terminal=g.terminal)  # exploring starts: uniform initial states
    res = q_learning(mdp, episodes=5_000, epsilon=0.3, max_steps=50, seed=0)
    v_star = value_iteration(mdp, tol=1e-12).values
    np.testing.assert_allclose(evaluate_policy(mdp, res.policy), v_star, atol=0.02)
    assert np.abs(res.q_values - q_star(mdp))[~mdp.terminal].max() < 0.1


def test_q_learning_from_a_gymnasium_env():
    import gymnasium as gym

    env = gym.make("FrozenLake-v1", is_slippery=False)
    # Deterministic dynamics: a constant step size of 1 (lr_exponent=0) is exact.
    res = q_learning(env, episodes=1_500, gamma=0.9, epsilon=0.3, lr_exponent=0.0, seed=0)
    mdp = mdp_from_gymnasium(env, gamma=0.9)
    start = int(np.argmax(mdp.initial))
    # Deterministic lake: the greedy policy must take a shortest path (6 steps) to the goal.
    assert evaluate_policy(mdp, res.policy)[start] == pytest.approx(0.9**5)
    assert res.q_values[start].max() == pytest.approx(0.9**5, abs=1e-9)
    with pytest.raises(ValueError, match="gamma is required"):
        q_learning(env, episodes=1)


def test_fitted_q_iteration_is_exact_on_a_dataset_that_is_the_mdp():
    # P[s, a] puts mass k/4 on successors, so a dataset holding each (s, a) with its four
    # sampled successors has empirical frequencies equal to P: FQI must reproduce Q* exactly.
    rng = np.random.default_rng(0)
    S, A = 6, 3
    succ = rng.integers(0, S, size=(S, A, 4))
    P = np.zeros((S, A, S))
    for s in range(S):
        for a in range(A):
            np.add.at(P[s, a], succ[s, a], 0.25)
    R_sas = rng.normal(size=(S, A, S))
    mdp = FiniteMDP(P, R_sas, 0.8, terminal=[5])
    data = [(s, a, R_sas[s, a, s2], s2, s2 == 5) for s in range(5) for a in range(A) for s2 in succ[s, a]]
    res = fitted_q_iteration(data, n_states=S, n_actions=A, gamma=0.8, tol=1e-13)
    assert res.converged
    np.testing.assert_allclose(res.q_values[:5], q_star(mdp)[:5], atol=1e-9)
    assert (res.counts[:5] == 4).all() and (res.counts[5] == 0).all()


def test_fitted_q_iteration_converges_with_more_data():
    mdp = random_mdp(3, S=5, A=2, gamma=0.7, successors=3, n_terminal=1, sas_rewards=True)
    live = ~mdp.terminal
    errs = []
    for n in (500, 200_000):
        data = sample_transitions(mdp, n, seed=1)
        res = fitted_q_iteration(data, n_states=5, n_actions=2, gamma=mdp.gamma)
        errs.append(np.abs(res.q_values - q_star(mdp))[live].max())
    assert errs[1] < 0.02 and errs[1] < errs[0]


def test_sample_transitions_follow_p():
    mdp = random_mdp(4, S=3, A=2, gamma=0.5, successors=3)
    d = sample_transitions(mdp, 60_000, seed=0)
    P = mdp.transition_tensor()
    for s in range(3):
        for a in range(2):
            mask = (d.states == s) & (d.actions == a)
            freq = np.bincount(d.next_states[mask], minlength=3) / mask.sum()
            np.testing.assert_allclose(freq, P[s, a], atol=0.03)


def test_fitted_q_dataset_formats_and_validation():
    data = [(0, 1, 1.0, 1, True), (1, 0, 0.5, 0, False)]
    arrays = tuple(np.array(c) for c in zip(*data))
    a = fitted_q_iteration(data, n_states=2, n_actions=2, gamma=0.9, q_init=7.0)
    b = fitted_q_iteration(arrays, n_states=2, n_actions=2, gamma=0.9, q_init=7.0)
    c = fitted_q_iteration(Transitions(*arrays), n_states=2, n_actions=2, gamma=0.9, q_init=7.0)
    np.testing.assert_array_equal(a.q_values, b.q_values)
    np.testing.assert_array_equal(a.q_values, c.q_values)
    # Q(0, 1) = 1 (terminal next state); Q(1, 0) = 0.5 + 0.9 * max(Q(0, .)); unseen pairs keep q_init.
    assert a.q_values[0, 1] == pytest.approx(1.0)
    assert a.q_values[0, 0] == 7.0 and a.q_values[1, 1] == 7.0
    assert a.q_values[1, 0] == pytest.approx(0.5 + 0.9 * 7.0)
    with pytest.raises(ValueError, match=r"dataset field a has value 3 outside \[0, 2\)"):
        fitted_q_iteration([(0, 3, 0.0, 1, False)], n_states=2, n_actions=2, gamma=0.9)
    with pytest.raises(ValueError, match="5-tuples"):
        fitted_q_iteration([(0, 1, 0.0)], n_states=2, n_actions=2, gamma=0.9)


def test_a_tuple_of_five_transitions_is_not_mistaken_for_columns():
    data = tuple((0, 0, float(i), 1, True) for i in range(5))  # five transitions of (0, 0)
    res = fitted_q_iteration(data, n_states=2, n_actions=1, gamma=0.9)
    assert res.counts[0, 0] == 5 and res.q_values[0, 0] == pytest.approx(2.0)  # mean reward
