"""Exact dynamic programming: policy evaluation, Q-values, advantages, policy and value iteration.

Notation: ``V[s]``, ``Q[s, a]``, ``A[s, a] = Q[s, a] - V[s]``; ``P`` and ``R`` as in
:class:`~taskrl.tabular.mdp.FiniteMDP` (terminal states have value 0). Every sweep below is one
sparse mat-vec with ``mdp.discounted_transitions`` (``gamma * P``, action-major ``[A * S, S]``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from taskrl.tabular.mdp import FiniteMDP
from taskrl.tabular.policies import check_policy, policy_chain

__all__ = [
    "Solution",
    "PolicyEvaluation",
    "bellman_backup",
    "evaluate_policy",
    "evaluate_policy_iterative",
    "q_values",
    "advantages",
    "greedy_policy",
    "policy_improvement",
    "policy_iteration",
    "value_iteration",
]

Solver = Literal["auto", "dense", "sparse", "krylov"]

#: Up to this many states "auto" uses a sparse LU (exact, single-threaded); above, a Krylov
#: method verified by its residual. A sparse LU of a *random* sparse MDP fills in almost
#: completely (measured ~20 s at 1e4 states), while BiCGSTAB needs a few dozen mat-vecs.
#: Dense LAPACK is avoided by default: multi-threaded OpenBLAS can be 30x slower on a busy machine.
LU_MAX_STATES = 1000


@dataclass(frozen=True, eq=False)
class Solution:
    """The result of policy iteration or value iteration.

    Attributes:
        values: ``V[s]``, shape ``[S]``.
        q_values: ``Q[s, a] = R[s, a] + gamma * sum_s' P[s, a, s'] V[s']``, shape ``[S, A]``.
        policy: greedy deterministic policy, int ``[S]``.
        iterations: policy-iteration improvement rounds, or value-iteration sweeps.
        converged: whether the stopping criterion was met before ``max_iterations``.
        seconds: wall-clock time of the solve.
    """

    values: np.ndarray
    q_values: np.ndarray
    policy: np.ndarray
    iterations: int
    converged: bool
    seconds: float

    @property
    def advantages(self) -> np.ndarray:
        """``A[s, a] = Q[s, a] - V[s]``, shape ``[S, A]``."""
        return self.q_values - self.values[:, None]


@dataclass(frozen=True, eq=False)
class PolicyEvaluation:
    """The result of iterative policy evaluation.

    Attributes:
        values: ``V_pi[s]`` after the last sweep, shape ``[S]``.
        iterations: number of sweeps.
        converged: whether the last change ``max_s |V_k+1 - V_k|`` fell below ``tol``.
        residual: that last change.
    """

    values: np.ndarray
    iterations: int
    converged: bool
    residual: float


def bellman_backup(mdp: FiniteMDP, values: np.ndarray) -> np.ndarray:
    """One Bellman backup ``Q[s, a] = R[s, a] + gamma * sum_s' P[s, a, s'] V[s']``, shape ``[S, A]``.

    Args:
        mdp: the MDP.
        values: any value function ``V``, shape ``[S]`` (terminal entries are ignored).
    """
    v = np.asarray(values, dtype=np.float64)
    if v.shape != (mdp.n_states,):
        raise ValueError(f"values has shape {v.shape}; expected ({mdp.n_states},)")
    return _backup(mdp, v).T.copy()


def _backup(mdp: FiniteMDP, v: np.ndarray) -> np.ndarray:
    """Bellman backup in action-major layout ``[A, S]``: one sparse mat-vec plus one add."""
    q = mdp.discounted_transitions @ v
    q += mdp.rewards_by_action.ravel()
    return q.reshape(mdp.n_actions, mdp.n_states)


def evaluate_policy(mdp: FiniteMDP, policy: Any, *, solver: Solver = "auto") -> np.ndarray:
    """Exact policy evaluation: solve ``(I - gamma P_pi) V = R_pi`` for ``V_pi``, shape ``[S]``.

    Args:
        mdp: the MDP.
        policy: deterministic ``[S]`` actions or stochastic ``[S, A]`` probabilities.
        solver: ``"dense"`` (``numpy.linalg.solve``), ``"sparse"`` (``scipy.sparse.linalg.spsolve``,
            a sparse LU: exact, but fill-in makes it slow on large random MDPs), ``"krylov"``
            (BiCGSTAB to relative residual 1e-12, falling back to GMRES and then LU), or
            ``"auto"`` (sparse LU up to ``LU_MAX_STATES`` states, else Krylov).

    Raises:
        ValueError: if ``I - gamma P_pi`` is singular, which happens when ``gamma = 1`` and the
            policy does not reach a terminal state with probability 1 from every state.
    """
    S = mdp.n_states
    gP_pi, R_pi = policy_chain(mdp, policy)
    M = (sp.identity(S, format="csr") - gP_pi).tocsr()
    if solver == "auto":
        solver = "sparse" if S <= LU_MAX_STATES else "krylov"
    if solver == "dense":
        try:
            V = np.linalg.solve(M.toarray(), R_pi)
        except np.linalg.LinAlgError:
            V = np.full(S, np.nan)
    elif solver == "sparse":
        V = _spsolve(M, R_pi)
    elif solver == "krylov":
        V = _krylov(M, R_pi)
    else:
        raise ValueError(f"solver={solver!r} is not one of 'auto', 'dense', 'sparse', 'krylov'")
    scale = max(1.0, float(np.abs(R_pi).max(initial=0.0)))
    if not np.all(np.isfinite(V)) or np.abs(M @ V - R_pi).max(initial=0.0) > 1e-6 * scale:
        raise ValueError(
            "policy evaluation failed: I - gamma * P_pi is singular (with gamma = 1 the policy "
            "must reach a terminal state with probability 1 from every state)"
        )
    return V


def _spsolve(M: sp.csr_matrix, b: np.ndarray) -> np.ndarray:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", spla.MatrixRankWarning)
        try:
            return np.asarray(spla.spsolve(M.tocsc(), b), dtype=np.float64)
        except RuntimeError:  # SuperLU: "factor is exactly singular"
            return np.full(M.shape[0], np.nan)


def _krylov(M: sp.csr_matrix, b: np.ndarray) -> np.ndarray:
    """Solve ``M x = b`` iteratively; ``M = I - gamma P_pi`` is well conditioned unless gamma ~ 1."""
    bnorm = max(float(np.linalg.norm(b)), 1e-300)
    for method in (spla.bicgstab, spla.gmres):
        x, info = method(M, b, rtol=1e-12, atol=0.0, maxiter=10 * M.shape[0])
        if info == 0 and np.all(np.isfinite(x)) and np.linalg.norm(M @ x - b) <= 1e-10 * bnorm:
            return x
    return _spsolve(M, b)


def evaluate_policy_iterative(
    mdp: FiniteMDP,
    policy: Any,
    *,
    tol: float = 1e-10,
    max_iterations: int = 100_000,
    values: np.ndarray | None = None,
) -> PolicyEvaluation:
    """Iterative policy evaluation: ``V_k+1 = R_pi + gamma P_pi V_k`` until ``max|V_k+1 - V_k| < tol``.

    Args:
        mdp: the MDP.
        policy: deterministic ``[S]`` actions or stochastic ``[S, A]`` probabilities.
        tol: stop when the sup-norm change of one sweep falls below this. For ``gamma < 1`` the
            error is then at most ``gamma * tol / (1 - gamma)``.
        max_iterations: sweep budget.
        values: initial guess ``V_0`` (default zeros); warm starts make this cheap inside
            policy iteration.
    """
    gP_pi, R_pi = policy_chain(mdp, policy)
    V = np.zeros(mdp.n_states) if values is None else np.array(values, dtype=np.float64)
    delta, k = np.inf, 0
    for k in range(1, max_iterations + 1):
        V_new = R_pi + gP_pi @ V  # Bellman expectation operator T_pi
        delta = float(np.abs(V_new - V).max(initial=0.0))
        V = V_new
        if delta < tol:
            break
    return PolicyEvaluation(V, k, bool(delta < tol), delta)


def q_values(mdp: FiniteMDP, policy: Any, *, solver: Solver = "auto") -> np.ndarray:
    """``Q_pi[s, a] = R[s, a] + gamma * sum_s' P[s, a, s'] V_pi[s']``, shape ``[S, A]`` (exact)."""
    return bellman_backup(mdp, evaluate_policy(mdp, policy, solver=solver))


def advantages(mdp: FiniteMDP, policy: Any, *, solver: Solver = "auto") -> np.ndarray:
    """``A_pi[s, a] = Q_pi[s, a] - V_pi[s]``, shape ``[S, A]`` (exact).

    ``sum_a pi(a|s) A_pi[s, a] = 0``; for a deterministic policy ``A_pi[s, pi(s)] = 0``.
    """
    V = evaluate_policy(mdp, policy, solver=solver)
    return bellman_backup(mdp, V) - V[:, None]


def greedy_policy(q: np.ndarray, *, current: np.ndarray | None = None, atol: float = 0.0) -> np.ndarray:
    """``pi(s) = argmax_a Q[s, a]``, int ``[S]``.

    Args:
        q: action values ``[S, A]``.
        current: a deterministic policy to keep wherever its action is within ``atol`` of the
            best; policy iteration needs this so that round-off ties cannot make it cycle.
        atol: tie tolerance used with ``current``.
    """
    best = np.argmax(q, axis=1)
    if current is None:
        return best
    idx = np.arange(q.shape[0])
    keep = q[idx, current] >= q[idx, best] - atol
    return np.where(keep, current, best)


def policy_improvement(mdp: FiniteMDP, policy: Any, *, solver: Solver = "auto") -> np.ndarray:
    """Greedy improvement ``pi'(s) = argmax_a Q_pi[s, a]`` (keeps ``pi(s)`` on exact ties)."""
    pi = check_policy(mdp, policy)
    q = q_values(mdp, pi, solver=solver)
    return greedy_policy(q, current=pi if pi.ndim == 1 else None, atol=_tie_tol(q, 1e-12))


def _tie_tol(q: np.ndarray, rel: float) -> float:
    """Differences below this are treated as round-off ties."""
    return rel * (1.0 + float(np.abs(q).max(initial=0.0)))


def policy_iteration(
    mdp: FiniteMDP,
    *,
    policy: Any = None,
    evaluation: Literal["exact", "iterative"] = "exact",
    solver: Solver = "auto",
    tol: float = 1e-10,
    max_iterations: int = 1_000,
) -> Solution:
    """Policy iteration (Howard): evaluate ``pi`` exactly, act greedily on ``Q_pi``, repeat until stable.

    Args:
        mdp: the MDP.
        policy: initial policy (default: action 0 everywhere); deterministic or stochastic.
        evaluation: ``"exact"`` solves the linear system each round; ``"iterative"`` runs
            Bellman expectation sweeps to ``tol``, warm-started from the previous values
            (modified policy iteration).
        solver: linear solver for exact evaluation, see :func:`evaluate_policy`.
        tol: tolerance of iterative evaluation.
        max_iterations: maximum number of improvement rounds.

    Returns:
        A :class:`Solution`; ``iterations`` counts evaluations, so a policy that is already
        optimal takes 1.
    """
    if evaluation not in ("exact", "iterative"):
        raise ValueError(f"evaluation={evaluation!r} is not one of 'exact', 'iterative'")
    t0 = time.perf_counter()
    pi = np.zeros(mdp.n_states, dtype=np.int64) if policy is None else check_policy(mdp, policy)
    V = np.zeros(mdp.n_states)
    converged, k = False, 0
    for k in range(1, max_iterations + 1):
        # Evaluation: V = (I - gamma P_pi)^-1 R_pi.
        if evaluation == "exact":
            V = evaluate_policy(mdp, pi, solver=solver)
        else:
            V = evaluate_policy_iterative(mdp, pi, tol=tol, values=V).values
        # Improvement: pi'(s) = argmax_a R(s, a) + gamma sum_s' P(s'|s, a) V(s').
        Q = _backup(mdp, V).T
        # A looser tie tolerance than policy_improvement: Krylov/iterative evaluation errors
        # must not flip near-tied actions back and forth.
        new_pi = greedy_policy(Q, current=pi if pi.ndim == 1 else None, atol=_tie_tol(Q, 1e-10))
        if pi.ndim == 1 and np.array_equal(new_pi, pi):
            converged = True  # V is now the fixed point of the Bellman optimality operator
            break
        pi = new_pi
    return Solution(V, np.ascontiguousarray(Q), pi, k, converged, time.perf_counter() - t0)


def value_iteration(
    mdp: FiniteMDP,
    *,
    tol: float = 1e-8,
    max_iterations: int = 100_000,
    values: np.ndarray | None = None,
) -> Solution:
    """Value iteration: ``V_k+1(s) = max_a R(s, a) + gamma sum_s' P(s'|s, a) V_k(s')``.

    Args:
        mdp: the MDP.
        tol: stop when ``max_s |V_k+1(s) - V_k(s)| < tol``; for ``gamma < 1`` the returned values
            are then within ``gamma * tol / (1 - gamma)`` of ``V*``.
        max_iterations: sweep budget.
        values: initial values ``V_0`` (default zeros).

    Returns:
        A :class:`Solution` with ``q_values`` the backup of the last iterate ``V_k``, ``values =
        max_a q_values`` and the greedy policy; ``iterations`` is the number of sweeps.
    """
    t0 = time.perf_counter()
    gP, R = mdp.discounted_transitions, mdp.rewards_by_action.ravel()
    S, A = mdp.n_states, mdp.n_actions
    V = np.zeros(S) if values is None else np.array(values, dtype=np.float64)
    delta, k = np.inf, 0
    for k in range(1, max_iterations + 1):
        Q = gP @ V  # gamma * sum_s' P(s'|s, a) V(s'), action-major [A * S]
        Q += R
        V_new = Q.reshape(A, S).max(axis=0)  # max over A contiguous rows: cheap
        delta = float(np.abs(V_new - V).max(initial=0.0))
        V = V_new
        if delta < tol:
            break
    # One more backup so that the returned V, Q and policy agree exactly: V = max_a Q, A <= 0.
    Q = np.ascontiguousarray(_backup(mdp, V).T)
    return Solution(Q.max(axis=1), Q, greedy_policy(Q), k, bool(delta < tol), time.perf_counter() - t0)
