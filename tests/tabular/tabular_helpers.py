"""Shared helpers for the tabular tests: random MDPs and an independent LP solver."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linprog

from taskrl.tabular import FiniteMDP


def random_mdp(
    seed: int,
    S: int,
    A: int,
    gamma: float,
    *,
    successors: int | None = None,
    n_terminal: int = 0,
    sparse: bool = False,
    sas_rewards: bool = False,
) -> FiniteMDP:
    """A random MDP; ``successors`` limits the support of each P(.|s, a)."""
    rng = np.random.default_rng(seed)
    P = np.zeros((S, A, S))
    k = S if successors is None else min(successors, S)
    for s in range(S):
        for a in range(A):
            support = rng.choice(S, size=k, replace=False)
            P[s, a, support] = rng.dirichlet(np.ones(k))
    R = rng.uniform(-1, 1, size=(S, A, S) if sas_rewards else (S, A))
    terminal = rng.choice(S, size=n_terminal, replace=False) if n_terminal else None
    P_in = sp.csr_matrix(P.reshape(S * A, S)) if sparse else P
    return FiniteMDP(P_in, R, gamma, terminal=terminal)


def lp_optimal_values(mdp: FiniteMDP) -> np.ndarray:
    """V* from the LP  min sum_s V(s)  s.t.  V(s) >= R(s, a) + gamma sum_s' P(s'|s, a) V(s').

    Written independently of the library's backup: uses the dense tensor and the terminal
    convention (V = 0 on terminal states, no constraints from them).
    """
    S, A = mdp.n_states, mdp.n_actions
    P = mdp.transition_tensor()
    live = ~mdp.terminal
    rows, rhs = [], []
    for s in np.flatnonzero(live):
        for a in range(A):
            row = mdp.gamma * P[s, a] * live  # no bootstrap from terminal successors
            row[s] -= 1.0
            rows.append(row)  # gamma P V - V(s) <= -R
            rhs.append(-mdp.R[s, a])
    bounds = [(None, None) if live[s] else (0.0, 0.0) for s in range(S)]
    if not rows:
        return np.zeros(S)
    res = linprog(
        np.ones(S),
        A_ub=np.array(rows),
        b_ub=np.array(rhs),
        bounds=bounds,
        method="highs",
        options={"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10},
    )
    assert res.status == 0, res.message
    return res.x
