"""Policies on a finite MDP: validation and the induced Markov chain ``(P_pi, R_pi)``.

A policy is either deterministic, an int array ``[S]`` of actions, or stochastic, a float array
``[S, A]`` of action probabilities (rows sum to 1).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from taskrl.tabular.mdp import FiniteMDP

__all__ = [
    "check_policy",
    "uniform_policy",
    "constant_policy",
    "proper_policy",
    "policy_chain",
    "as_stochastic",
]


def check_policy(mdp: FiniteMDP, policy: Any) -> np.ndarray:
    """Validate ``policy`` for ``mdp``; return an int64 ``[S]`` or float64 ``[S, A]`` copy.

    Raises:
        ValueError: naming the offending state when the policy does not fit the MDP.
    """
    S, A = mdp.n_states, mdp.n_actions
    arr = np.asarray(policy)
    if arr.ndim == 1:
        if arr.shape != (S,):
            raise ValueError(f"policy has shape {arr.shape}; expected ({S},) actions or ({S}, {A}) probabilities")
        if not np.issubdtype(arr.dtype, np.integer):
            if not np.all(np.isfinite(arr)) or not np.all(arr == np.round(arr)):
                raise ValueError("a deterministic policy must hold integer actions")
        arr = arr.astype(np.int64)
        bad = np.flatnonzero((arr < 0) | (arr >= A))
        if bad.size:
            s = int(bad[0])
            raise ValueError(f"policy[s={s}] = {arr[s]} is not an action in [0, {A})")
        return arr
    if arr.shape != (S, A):
        raise ValueError(f"policy has shape {arr.shape}; expected ({S},) actions or ({S}, {A}) probabilities")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)) or (arr < 0).any():
        s = int(np.flatnonzero(~(np.isfinite(arr) & (arr >= 0)).all(axis=1))[0])
        raise ValueError(f"policy[s={s}] has negative or non-finite probabilities")
    sums = arr.sum(axis=1)
    bad = np.flatnonzero(np.abs(sums - 1.0) > 1e-8)
    if bad.size:
        s = int(bad[0])
        raise ValueError(f"policy[s={s}] sums to {sums[s]:.6g}; action probabilities must sum to 1")
    return arr


def uniform_policy(mdp: FiniteMDP) -> np.ndarray:
    """The uniformly random policy, ``[S, A]``."""
    return np.full((mdp.n_states, mdp.n_actions), 1.0 / mdp.n_actions)


def constant_policy(mdp: FiniteMDP, action: int) -> np.ndarray:
    """The deterministic policy that always takes ``action``, ``[S]``."""
    if not 0 <= action < mdp.n_actions:
        raise ValueError(f"action={action} is not an action in [0, {mdp.n_actions})")
    return np.full(mdp.n_states, action, dtype=np.int64)


def proper_policy(mdp: FiniteMDP) -> np.ndarray:
    """A deterministic policy that reaches a terminal state with probability 1 from every state.

    Backward breadth-first search from the terminal states: each state takes an action with a
    positive probability of moving one step closer (in the support graph of ``P``) to a terminal
    state, so from every state some positive-probability path ends in a terminal state. With
    ``gamma = 1`` policy iteration must start from such a policy, or evaluation is singular.

    Raises:
        ValueError: if some state cannot reach any terminal state whatever the actions.
    """
    S, A = mdp.n_states, mdp.n_actions
    into = mdp.P.tocsc()  # column s' lists the rows s * A + a that can move to s'
    policy = np.zeros(S, dtype=np.int64)
    reached = mdp.terminal.copy()
    frontier = np.flatnonzero(reached)
    while frontier.size:
        rows = np.concatenate([into.indices[into.indptr[c] : into.indptr[c + 1]] for c in frontier])
        states, first = np.unique(rows // A, return_index=True)
        new = ~reached[states]
        policy[states[new]] = rows[first[new]] % A
        reached[states[new]] = True
        frontier = states[new]
    if not reached.all():
        s = int(np.flatnonzero(~reached)[0])
        raise ValueError(
            f"state {s} ({mdp.state_names[s]}) cannot reach a terminal state under any policy; "
            "with gamma = 1 its value is undefined"
        )
    return policy


def as_stochastic(mdp: FiniteMDP, policy: Any) -> np.ndarray:
    """Action probabilities ``[S, A]`` of any policy."""
    pi = check_policy(mdp, policy)
    if pi.ndim == 2:
        return pi
    out = np.zeros((mdp.n_states, mdp.n_actions))
    out[np.arange(mdp.n_states), pi] = 1.0
    return out


def policy_chain(mdp: FiniteMDP, policy: Any) -> tuple[sp.csr_matrix, np.ndarray]:
    """The discounted Markov chain of a policy: ``(gamma * P_pi [S, S], R_pi [S])``.

    ``P_pi(s, s') = sum_a pi(a|s) P(s'|s, a)`` and ``R_pi(s) = sum_a pi(a|s) R(s, a)``, under the
    terminal convention (terminal rows/columns of ``gamma * P`` are zero, terminal rewards zero).
    """
    S, A = mdp.n_states, mdp.n_actions
    pi = check_policy(mdp, policy)
    gP, R = mdp.discounted_transitions, mdp.rewards_by_action  # [A*S, S], [A, S]
    if pi.ndim == 1:
        # Deterministic: pick row a * S + s for each s -- a row gather, no arithmetic.
        return _gather_rows(gP, pi * S + np.arange(S)), R[pi, np.arange(S)].copy()
    # Stochastic: P_pi = sum_a diag(pi[:, a]) gP_a, written as one sparse product [S, A*S] @ [A*S, S].
    weights = sp.csr_matrix((pi.T.ravel(), (np.tile(np.arange(S), A), np.arange(A * S))), shape=(S, A * S))
    return (weights @ gP).tocsr(), np.einsum("as,sa->s", R, pi)


def _gather_rows(M: sp.csr_matrix, rows: np.ndarray) -> sp.csr_matrix:
    """``M[rows]`` for CSR ``M``, vectorised (scipy's fancy row indexing is ~20x slower here)."""
    starts, ends = M.indptr[rows], M.indptr[rows + 1]
    lengths = ends - starts
    indptr = np.concatenate([[0], np.cumsum(lengths)])
    # Position in M.data of each output entry: its row's start plus its offset within the row.
    src = np.repeat(starts - indptr[:-1], lengths) + np.arange(indptr[-1])
    return sp.csr_matrix((M.data[src], M.indices[src], indptr), shape=(len(rows), M.shape[1]))
