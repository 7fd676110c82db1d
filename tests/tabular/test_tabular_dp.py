"""Policy evaluation, Q-values, advantages, policy iteration and value iteration."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tabular_helpers import lp_optimal_values, random_mdp

from taskrl.tabular import (
    FiniteMDP,
    advantages,
    bellman_backup,
    evaluate_policy,
    evaluate_policy_iterative,
    grid_world,
    mdp_from_gymnasium,
    policy_improvement,
    policy_iteration,
    q_values,
    uniform_policy,
    value_iteration,
)

mdp_params = st.tuples(
    st.integers(0, 2**31 - 1),  # seed
    st.integers(1, 8),  # S
    st.integers(1, 4),  # A
    st.floats(0.0, 0.95),  # gamma
    st.integers(1, 8),  # successors per (s, a)
    st.booleans(),  # sparse input
)


@settings(max_examples=40, deadline=None)
@given(mdp_params, st.integers(0, 2))
def test_policy_and_value_iteration_agree_with_linear_programming(params, n_terminal):
    seed, S, A, gamma, k, sparse = params
    mdp = random_mdp(seed, S, A, gamma, successors=k, n_terminal=min(n_terminal, S - 1), sparse=sparse)
    v_lp = lp_optimal_values(mdp)
    pi = policy_iteration(mdp)
    vi = value_iteration(mdp, tol=1e-12)
    assert pi.converged and vi.converged
    np.testing.assert_allclose(pi.values, v_lp, atol=1e-6)
    np.testing.assert_allclose(vi.values, v_lp, atol=1e-6)
    np.testing.assert_allclose(pi.values, vi.values, atol=1e-8)
    # Both greedy policies are optimal (they may differ only on ties).
    np.testing.assert_allclose(evaluate_policy(mdp, vi.policy), v_lp, atol=1e-6)
    # Bellman optimality: V* = max_a Q*, and the policy attains it.
    np.testing.assert_allclose(pi.q_values.max(axis=1), pi.values, atol=1e-9)
    np.testing.assert_allclose(pi.q_values[np.arange(S), pi.policy], pi.values, atol=1e-9)
    assert (pi.advantages <= 1e-9).all()


@settings(max_examples=30, deadline=None)
@given(mdp_params)
def test_exact_and_iterative_evaluation_agree(params):
    seed, S, A, gamma, k, sparse = params
    mdp = random_mdp(seed, S, A, gamma, successors=k, n_terminal=1 if S > 1 else 0, sparse=sparse)
    pi = np.random.default_rng(seed).dirichlet(np.ones(A), size=S)
    v = evaluate_policy(mdp, pi)
    for solver in ("dense", "sparse", "krylov"):
        np.testing.assert_allclose(evaluate_policy(mdp, pi, solver=solver), v, atol=1e-9)
    it = evaluate_policy_iterative(mdp, pi, tol=1e-12)
    assert it.converged
    np.testing.assert_allclose(it.values, v, atol=1e-9)
    # V_pi is the fixed point of T_pi: V = sum_a pi(a|s) Q_pi(s, a).
    q = q_values(mdp, pi)
    np.testing.assert_allclose((pi * q).sum(axis=1), v, atol=1e-9)
    # Advantages average to zero under the policy itself.
    np.testing.assert_allclose((pi * advantages(mdp, pi)).sum(axis=1), 0.0, atol=1e-9)


def test_evaluation_matches_a_hand_computed_chain():
    # Two states: s0 -a-> s1 (reward 1), s1 -> s1 (reward 2) forever; gamma = 0.5.
    P = np.zeros((2, 1, 2))
    P[0, 0, 1] = P[1, 0, 1] = 1.0
    mdp = FiniteMDP(P, np.array([[1.0], [2.0]]), 0.5)
    v = evaluate_policy(mdp, [0, 0])
    np.testing.assert_allclose(v, [1 + 0.5 * 4.0, 4.0])  # V(s1) = 2 / (1 - 0.5)


def test_terminal_states_absorb_with_zero_value():
    # s0 -> terminal s1 with reward 1; s1's own (ignored) row would pay 10 forever.
    P = np.zeros((2, 1, 2))
    P[0, 0, 1] = P[1, 0, 1] = 1.0
    mdp = FiniteMDP(P, np.array([[1.0], [10.0]]), 0.9, terminal=[1])
    sol = value_iteration(mdp)
    np.testing.assert_allclose(sol.values, [1.0, 0.0])
    np.testing.assert_allclose(bellman_backup(mdp, np.array([5.0, 123.0])), [[1.0], [0.0]])


def test_policy_improvement_theorem_on_random_mdps():
    for seed in range(10):
        mdp = random_mdp(seed, S=12, A=3, gamma=0.9, successors=3, n_terminal=2)
        pi = uniform_policy(mdp)
        v = evaluate_policy(mdp, pi)
        new = policy_improvement(mdp, pi)
        v_new = evaluate_policy(mdp, new)
        assert (v_new >= v - 1e-12).all()
        # The greedy action has non-negative advantage everywhere.
        assert (advantages(mdp, pi)[np.arange(12), new] >= -1e-12).all()


def test_policy_iteration_iterative_evaluation_variant():
    mdp = random_mdp(7, S=30, A=4, gamma=0.9, successors=4)
    exact = policy_iteration(mdp)
    modified = policy_iteration(mdp, evaluation="iterative", tol=1e-12)
    np.testing.assert_allclose(modified.values, exact.values, atol=1e-8)
    assert exact.iterations <= 10


def test_value_iteration_stops_within_the_contraction_bound():
    mdp = random_mdp(11, S=20, A=3, gamma=0.9, successors=5)
    v_star = lp_optimal_values(mdp)
    tol = 1e-3
    vi = value_iteration(mdp, tol=tol)
    assert vi.converged and vi.iterations > 5
    assert np.abs(vi.values - v_star).max() <= 0.9 * tol / 0.1 + 1e-9
    capped = value_iteration(mdp, tol=1e-14, max_iterations=3)
    assert capped.iterations == 3 and not capped.converged


def test_improper_policy_with_gamma_one_raises():
    g = grid_world(layout=["S.#", "..G"], slip=0.0, gamma=1.0)
    stay = np.zeros(g.n_states, dtype=int)  # "up" from the top row: bumps into the edge forever
    with pytest.raises(ValueError, match="singular"):
        evaluate_policy(g, stay)
    sol = value_iteration(g, tol=1e-12)  # value iteration still solves it
    assert sol.values[0] == pytest.approx(1.0)


def test_large_sparse_mdp_krylov_path():
    mdp = random_mdp(5, S=1500, A=3, gamma=0.95, successors=3, sparse=True)
    pi = policy_iteration(mdp)  # auto -> Krylov above 1000 states
    vi = value_iteration(mdp, tol=1e-11)
    np.testing.assert_allclose(pi.values, vi.values, atol=1e-8)


def test_greedy_policy_picks_the_first_maximum_and_keeps_tied_current_actions():
    from taskrl.tabular import greedy_policy

    q = np.array([[1.0, 3.0, 3.0], [2.0, 2.0, 0.0], [0.0, 0.0, 5.0]])
    np.testing.assert_array_equal(greedy_policy(q), [1, 0, 2])
    np.testing.assert_array_equal(greedy_policy(q, current=np.array([2, 1, 0])), [2, 1, 2])
    np.testing.assert_array_equal(greedy_policy(q, current=np.array([0, 1, 0]), atol=2.5), [0, 1, 2])
    rng = np.random.default_rng(0)
    for A in (1, 7, 300):  # 300 actions takes the np.argmax path
        q = rng.integers(0, 4, size=(50, A)).astype(float)  # many exact ties
        np.testing.assert_array_equal(greedy_policy(q), q.argmax(axis=1))


def test_deterministic_policy_chain_matches_the_dense_tensor():
    from taskrl.tabular import policy_chain

    mdp = random_mdp(2, S=9, A=4, gamma=0.8, successors=3, n_terminal=2, sparse=True)
    pi = np.random.default_rng(2).integers(0, 4, size=9)
    gP, R = policy_chain(mdp, pi)
    P = mdp.transition_tensor()[np.arange(9), pi] * 0.8
    P[mdp.terminal] = 0.0
    P[:, mdp.terminal] = 0.0
    np.testing.assert_allclose(gP.toarray(), P, atol=1e-15)
    np.testing.assert_allclose(R, np.where(mdp.terminal, 0.0, mdp.R[np.arange(9), pi]))


def test_krylov_falls_back_when_bicgstab_breaks_down():
    from taskrl.tabular import CHILL, constant_policy, drummer

    mdp = drummer()  # finite-horizon chain: BiCGSTAB breaks down on the always-chill system
    chill = constant_policy(mdp, CHILL)
    np.testing.assert_allclose(
        evaluate_policy(mdp, chill, solver="krylov"), evaluate_policy(mdp, chill, solver="sparse"), atol=1e-12
    )


def test_undiscounted_policy_iteration_starts_from_a_proper_policy():
    from taskrl.tabular import proper_policy

    cliff = mdp_from_gymnasium("CliffWalking-v1", gamma=1.0)
    evaluate_policy(cliff, proper_policy(cliff))  # not singular: it terminates
    pi = policy_iteration(cliff)  # action 0 ("up") everywhere would be singular
    vi = value_iteration(cliff, tol=1e-12)
    assert pi.converged
    np.testing.assert_allclose(pi.values, vi.values, atol=1e-9)
    assert pi.values[36] == pytest.approx(-13.0)  # 13 steps along the cliff edge
    with pytest.raises(ValueError, match="state 0 .* cannot reach a terminal state"):
        proper_policy(grid_world(layout=["S#G"], gamma=1.0))
