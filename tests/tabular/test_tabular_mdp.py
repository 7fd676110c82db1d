"""FiniteMDP validation, layouts, gymnasium import and policy helpers."""

import re

import numpy as np
import pytest
import scipy.sparse as sp
from tabular_helpers import random_mdp

from taskrl.tabular import FiniteMDP, check_policy, mdp_from_gymnasium, policy_chain


def _good():
    P = np.zeros((3, 2, 3))
    P[0, 0, 1] = P[0, 1, 2] = 1.0
    P[1, :, 2] = 1.0
    P[2, :, 2] = 1.0
    R = np.array([[0.0, 1.0], [2.0, 2.0], [0.0, 0.0]])
    return P, R


def test_valid_mdp_layouts_agree():
    P, R = _good()
    dense = FiniteMDP(P, R, 0.9, terminal=[2])
    sparse = FiniteMDP(sp.csr_matrix(P.reshape(6, 3)), R, 0.9, terminal=np.array([False, False, True]))
    assert (dense.P != sparse.P).nnz == 0
    np.testing.assert_array_equal(dense.transition_tensor(), P)
    assert dense.n_states == 3 and dense.n_actions == 2
    # Default initial distribution: uniform over non-terminal states.
    np.testing.assert_allclose(dense.initial, [0.5, 0.5, 0.0])
    # Action-major backup matrix: gamma-scaled, terminal columns zeroed.
    M = dense.discounted_transitions.toarray()
    assert M.shape == (6, 3)
    assert M[0 * 3 + 0, 1] == pytest.approx(0.9)  # s=0, a=0 -> s'=1
    assert M[:, 2].sum() == 0.0  # nothing bootstraps from terminal state 2


@pytest.mark.parametrize(
    "mutate, message",
    [
        (
            lambda P, R: (P * np.where(np.arange(3)[:, None, None] == 1, 0.8, 1.0), R, 0.9, [2]),
            r"P\[s=1, a=0\] sums to 0.8; each row of P must sum to 1",
        ),
        (lambda P, R: (P + _neg(P), R, 0.9, [2]), r"P\[s=0, a=0, s'=0\] = -0.5 is negative"),
        (lambda P, R: (P, R[:, :1], 0.9, [2]), r"R has shape \(3, 1\).*\(S, A\) = \(3, 2\)"),
        (lambda P, R: (P[:, :, :2], R, 0.9, [2]), r"P has shape \(3, 2, 2\); dense P must have shape \[S, A, S\]"),
        (lambda P, R: (P, R, 1.5, [2]), r"gamma=1.5 is outside \[0, 1\)"),
        (lambda P, R: (P, R, -0.1, [2]), r"gamma=-0.1 is outside \[0, 1\)"),
        (lambda P, R: (P, R, 1.0, None), r"gamma=1 needs terminal states"),
        (lambda P, R: (P, R, 0.9, [7]), r"terminal state 7 is not a state index"),
        (lambda P, R: (P, R * np.nan, 0.9, [2]), r"R has non-finite entries"),
    ],
)
def test_malformed_mdps_raise(mutate, message):
    P, R = _good()
    P2, R2, gamma, terminal = mutate(P, R)
    with pytest.raises(ValueError, match=message):
        FiniteMDP(P2, R2, gamma, terminal=terminal)


def _neg(P):
    out = np.zeros_like(P)
    out[0, 0, 0], out[0, 0, 1] = -0.5, 0.5
    return out


def test_more_malformed_inputs():
    P, R = _good()
    with pytest.raises(ValueError, match=r"sparse P must have shape \[S \* A, S\]"):
        FiniteMDP(sp.csr_matrix(np.ones((5, 3)) / 3), R, 0.9)
    with pytest.raises(ValueError, match="initial distribution sums to 0.5"):
        FiniteMDP(P, R, 0.9, terminal=[2], initial=[0.5, 0.0, 0.0])
    with pytest.raises(ValueError, match="action_names has 3 entries; expected 2"):
        FiniteMDP(P, R, 0.9, terminal=[2], action_names=["a", "b", "c"])
    # Rows of a non-terminal state may not be empty, terminal rows may.
    P_empty = P.copy()
    P_empty[2] = 0.0
    FiniteMDP(P_empty, R, 0.9, terminal=[2])
    with pytest.raises(ValueError, match=r"P\[s=2, a=0\] sums to 0"):
        FiniteMDP(P_empty, R, 0.9)


def test_gamma_one_allowed_with_terminal_states():
    P, R = _good()
    assert FiniteMDP(P, R, 1.0, terminal=[2]).gamma == 1.0


def test_sas_rewards_are_reduced_to_expected_rewards():
    mdp = random_mdp(3, S=5, A=3, gamma=0.9, sas_rewards=True)
    P = mdp.transition_tensor()
    R_sas = np.zeros_like(P)
    # Recover R[s, a, s'] on the support from the stored per-transition rewards.
    Pa = mdp.P_by_action
    rows = np.repeat(np.arange(Pa.shape[0]), np.diff(Pa.indptr))
    R_sas[rows % 5, rows // 5, Pa.indices] = mdp.transition_rewards
    np.testing.assert_allclose(mdp.R, (P * R_sas).sum(-1), atol=1e-12)
    # And against an independent reduction of the dense inputs.
    rng = np.random.default_rng(0)
    P2 = rng.dirichlet(np.ones(4), size=(4, 2))
    R2 = rng.normal(size=(4, 2, 4))
    np.testing.assert_allclose(FiniteMDP(P2, R2, 0.5).R, np.einsum("sat,sat->sa", P2, R2), atol=1e-12)


def test_policy_validation_messages():
    mdp = random_mdp(0, S=4, A=2, gamma=0.9)
    with pytest.raises(ValueError, match=r"policy\[s=2\] = 5 is not an action in \[0, 2\)"):
        check_policy(mdp, [0, 1, 5, 0])
    with pytest.raises(ValueError, match=r"policy has shape \(3,\)"):
        check_policy(mdp, [0, 1, 0])
    with pytest.raises(ValueError, match=r"policy\[s=1\] sums to 0.5"):
        check_policy(mdp, [[1, 0], [0.25, 0.25], [1, 0], [0, 1]])


def test_stochastic_policy_chain_mixes_deterministic_ones():
    mdp = random_mdp(1, S=6, A=3, gamma=0.8, n_terminal=1)
    pi = np.random.default_rng(1).dirichlet(np.ones(3), size=6)
    gP, R = policy_chain(mdp, pi)
    mix_P = sum(pi[:, [a]] * policy_chain(mdp, np.full(6, a))[0].toarray() for a in range(3))
    mix_R = sum(pi[:, a] * policy_chain(mdp, np.full(6, a))[1] for a in range(3))
    np.testing.assert_allclose(gP.toarray(), mix_P, atol=1e-14)
    np.testing.assert_allclose(R, mix_R, atol=1e-14)


def test_from_gymnasium_frozenlake():
    import gymnasium as gym

    env = gym.make("FrozenLake-v1")
    mdp = mdp_from_gymnasium(env, gamma=0.9)
    desc = "".join(b"".join(r).decode() for r in env.unwrapped.desc)
    assert mdp.n_states == 16 and mdp.n_actions == 4
    np.testing.assert_array_equal(mdp.terminal, [c in "HG" for c in desc])
    assert mdp.initial[0] == 1.0
    # Slippery: from state 14 (left of the goal) moving right reaches the goal with p = 1/3,
    # which is the only rewarding transition.
    assert mdp.transition_tensor()[14, 2, 15] == pytest.approx(1 / 3)
    assert mdp.R[14, 2] == pytest.approx(1 / 3)
    assert mdp.grid is not None and mdp.grid.rows[0] == "SFFF"


@pytest.mark.parametrize("name, S, A, n_terminal", [("CliffWalking-v1", 48, 4, 1), ("Taxi-v4", 500, 6, 4)])
def test_from_gymnasium_other_toy_text(name, S, A, n_terminal):
    mdp = mdp_from_gymnasium(name, gamma=0.95)
    assert (mdp.n_states, mdp.n_actions, int(mdp.terminal.sum())) == (S, A, n_terminal)
    assert re.match(name.split("-")[0], mdp.name)


def test_from_gymnasium_rejects_envs_without_a_table():
    import gymnasium as gym

    with pytest.raises(ValueError, match="no transition table"):
        mdp_from_gymnasium(gym.make("CartPole-v1"))
