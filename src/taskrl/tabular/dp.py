"""Exact dynamic programming: policy evaluation, Q-values, advantages, policy and value iteration.

Notation: ``V[s]``, ``Q[s, a]``, ``A[s, a] = Q[s, a] - V[s]``; ``P`` and ``R`` as in
[`FiniteMDP`][taskrl.tabular.mdp.FiniteMDP] (terminal states have value 0). Every sweep below is one
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
from taskrl.tabular.policies import check_policy, policy_chain, proper_policy

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
#: method verified by its residual, with LU as the fallback. A sparse LU of a *random* sparse MDP
#: fills in almost completely (measured ~20 s at 1e4 states), while BiCGSTAB needs a few dozen
#: mat-vecs. Dense LAPACK is not the default: multi-threaded OpenBLAS can be 30x slower on a
#: busy machine.
LU_MAX_STATES = 200
#: When BiCGSTAB fails (e.g. breaks down on a finite-horizon chain), systems up to this size go
#: straight to LU; larger ones try GMRES first.
LU_FALLBACK_MAX_STATES = 2000


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


def _as_values(mdp: FiniteMDP, values: Any, field: str = "values") -> np.ndarray:
    v = np.array(values, dtype=np.float64)  # a copy: callers may update it in place
    if v.shape != (mdp.n_states,):
        raise ValueError(f"{field} has shape {v.shape}; expected ({mdp.n_states},)")
    return v


def bellman_backup(mdp: FiniteMDP, values: np.ndarray) -> np.ndarray:
    """One Bellman backup ``Q[s, a] = R[s, a] + gamma * sum_s' P[s, a, s'] V[s']``, shape ``[S, A]``.

    Args:
        mdp: the MDP.
        values: any value function ``V``, shape ``[S]`` (terminal entries are ignored).
    """
    return _backup(mdp, _as_values(mdp, values)).T.copy()


def _backup(mdp: FiniteMDP, v: np.ndarray) -> np.ndarray:
    """Bellman backup in action-major layout ``[A, S]``: one sparse mat-vec plus one add."""
    q = mdp.discounted_transitions @ v
    q += mdp.rewards_by_action.ravel()
    return q.reshape(mdp.n_actions, mdp.n_states)


def evaluate_policy(mdp: FiniteMDP, policy: Any, *, solver: Solver = "auto", values: np.ndarray | None = None) -> np.ndarray:
    """Exact policy evaluation: solve ``(I - gamma P_pi) V = R_pi`` for ``V_pi``, shape ``[S]``.

    Args:
        mdp: the MDP.
        policy: deterministic ``[S]`` actions or stochastic ``[S, A]`` probabilities.
        solver: ``"dense"`` (``numpy.linalg.solve``), ``"sparse"`` (``scipy.sparse.linalg.spsolve``,
            a sparse LU: exact, but fill-in makes it slow on large random MDPs), ``"krylov"``
            (BiCGSTAB to relative residual 1e-12, falling back to GMRES and/or LU), or
            ``"auto"`` (sparse LU up to ``LU_MAX_STATES`` states, else Krylov).
        values: initial guess for the Krylov solver (policy iteration passes the previous
            policy's values); ignored by the direct solvers.

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
        V = _krylov(M, R_pi, None if values is None else _as_values(mdp, values))
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


def _dot(x: np.ndarray, y: np.ndarray) -> float:
    # einsum's own loop, not BLAS: multi-threaded BLAS dots of this size are slow on a busy machine.
    return float(np.einsum("i,i->", x, y))


def _bicgstab(M: sp.csr_matrix, b: np.ndarray, x: np.ndarray, rtol: float, maxiter: int) -> np.ndarray | None:
    """BiCGSTAB (van der Vorst, 1992) for ``M x = b``; ``None`` on breakdown or no convergence.

    Each iteration costs two sparse mat-vecs and a few vector updates.
    """
    target = rtol * np.sqrt(_dot(b, b))
    r = b - M @ x
    r_hat = r.copy()
    rho = alpha = omega = 1.0
    v = np.zeros_like(b)
    p = np.zeros_like(b)
    for _ in range(maxiter):
        if np.sqrt(_dot(r, r)) <= target:
            return x
        rho_new = _dot(r_hat, r)
        if rho_new == 0.0 or omega == 0.0:
            return None  # breakdown
        p = r + (rho_new / rho) * (alpha / omega) * (p - omega * v)
        v = M @ p
        denom = _dot(r_hat, v)
        if denom == 0.0:
            return None
        alpha = rho_new / denom
        s = r - alpha * v
        t = M @ s
        tt = _dot(t, t)
        omega = _dot(t, s) / tt if tt > 0 else 0.0
        x = x + alpha * p + omega * s
        r = s - omega * t
        rho = rho_new
    return x if np.sqrt(_dot(r, r)) <= target else None


def _krylov(M: sp.csr_matrix, b: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
    """Solve ``M x = b`` for ``M = I - gamma P_pi`` iteratively, checking the residual."""
    n = M.shape[0]
    bnorm = max(np.sqrt(_dot(b, b)), 1e-300)

    def ok(x: np.ndarray | None) -> bool:
        if x is None or not np.all(np.isfinite(x)):
            return False
        res = M @ x - b
        return bool(np.sqrt(_dot(res, res)) <= 1e-10 * bnorm)

    # Start from the given guess or from b, the first term of the Neumann series of M^-1.
    x = _bicgstab(M, b, b.copy() if x0 is None else x0.copy(), 1e-12, min(10 * n, 5_000))
    if ok(x):
        return x
    if n > LU_FALLBACK_MAX_STATES:
        x, info = spla.gmres(M, b, rtol=1e-12, atol=0.0, maxiter=min(10 * n, 5_000))
        if info == 0 and ok(x):
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
    V = np.zeros(mdp.n_states) if values is None else _as_values(mdp, values)
    delta, k = np.inf, 0
    for k in range(1, max_iterations + 1):  # noqa: B007 (k: the iterations run, reported after the loop)
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
    """``pi(s) = argmax_a Q[s, a]`` (the first maximal action), int ``[S]``.

    Args:
        q: action values ``[S, A]``.
        current: a deterministic policy to keep wherever its action is within ``atol`` of the
            best; policy iteration needs this so that round-off ties cannot make it cycle.
        atol: tie tolerance used with ``current``.
    """
    q_am = np.ascontiguousarray(np.asarray(q, dtype=np.float64).T)  # free for Q's from this module
    return _greedy_am(q_am, current, atol)


def _greedy_am(q_am: np.ndarray, current: np.ndarray | None, atol: float) -> np.ndarray:
    """Greedy policy from action-major ``Q [A, S]``.

    ``np.argmax(axis=0)`` costs about as much as a whole sparse mat-vec (it loops over S short
    rows), so the first maximal action is found with vectorised passes over ``[A, S]`` instead:
    weight the indicator ``Q == max`` by ``A - a`` and take the max over actions.
    """
    A, S = q_am.shape
    m = q_am.max(axis=0)
    if A < 256:
        weights = np.arange(A, 0, -1, dtype=np.uint8)[:, None]
        best = A - (np.equal(q_am, m).view(np.uint8) * weights).max(axis=0).astype(np.int64)
    else:
        best = np.argmax(q_am, axis=0)
    if current is None:
        return best
    keep = q_am[current, np.arange(S)] >= m - atol
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
        policy: initial policy; deterministic or stochastic. Default: action 0 everywhere, or
            for ``gamma = 1`` a [`proper_policy`][taskrl.tabular.policies.proper_policy] (one that
            terminates), without which the first evaluation could be singular.
        evaluation: ``"exact"`` solves the linear system each round; ``"iterative"`` runs
            Bellman expectation sweeps to ``tol``, warm-started from the previous values
            (modified policy iteration).
        solver: linear solver for exact evaluation, see `evaluate_policy`.
        tol: tolerance of iterative evaluation.
        max_iterations: maximum number of improvement rounds.

    Returns:
        A `Solution`; ``iterations`` counts evaluations, so a policy that is already
        optimal takes 1.
    """
    if evaluation not in ("exact", "iterative"):
        raise ValueError(f"evaluation={evaluation!r} is not one of 'exact', 'iterative'")
    t0 = time.perf_counter()
    if policy is not None:
        pi = check_policy(mdp, policy)
    elif mdp.gamma < 1.0:
        pi = np.zeros(mdp.n_states, dtype=np.int64)
    else:  # undiscounted: start from a policy that terminates, or its values are infinite
        pi = proper_policy(mdp)
    V = np.zeros(mdp.n_states)
    converged, k = False, 0
    for k in range(1, max_iterations + 1):
        # Evaluation: V = (I - gamma P_pi)^-1 R_pi.
        if evaluation == "exact":
            V = evaluate_policy(mdp, pi, solver=solver, values=V if k > 1 else None)
        else:
            V = evaluate_policy_iterative(mdp, pi, tol=tol, values=V).values
        # Improvement: pi'(s) = argmax_a R(s, a) + gamma sum_s' P(s'|s, a) V(s').
        Q_am = _backup(mdp, V)
        # A looser tie tolerance than policy_improvement: Krylov/iterative evaluation errors
        # must not flip near-tied actions back and forth.
        new_pi = _greedy_am(Q_am, pi if pi.ndim == 1 else None, _tie_tol(Q_am, 1e-10))
        if pi.ndim == 1 and np.array_equal(new_pi, pi):
            converged = True  # V is now the fixed point of the Bellman optimality operator
            break
        pi = new_pi
    return Solution(V, np.ascontiguousarray(Q_am.T), pi, k, converged, time.perf_counter() - t0)


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
        A `Solution` with ``q_values`` the backup of the last iterate ``V_k``, ``values =
        max_a q_values`` and the greedy policy; ``iterations`` is the number of sweeps.
    """
    t0 = time.perf_counter()
    gP, R = mdp.discounted_transitions, mdp.rewards_by_action.ravel()
    S, A = mdp.n_states, mdp.n_actions
    V = np.zeros(S) if values is None else _as_values(mdp, values)
    delta, k = np.inf, 0
    for k in range(1, max_iterations + 1):  # noqa: B007 (k: the iterations run, reported after the loop)
        Q = gP @ V  # gamma * sum_s' P(s'|s, a) V(s'), action-major [A * S]
        Q += R
        V_new = Q.reshape(A, S).max(axis=0)  # max over A contiguous rows: cheap
        delta = float(np.abs(V_new - V).max(initial=0.0))
        V = V_new
        if delta < tol:
            break
    # One more backup so that the returned V, Q and policy agree exactly: V = max_a Q, A <= 0.
    Q_am = _backup(mdp, V)
    policy = _greedy_am(Q_am, None, 0.0)
    return Solution(Q_am.max(axis=0), np.ascontiguousarray(Q_am.T), policy, k, bool(delta < tol), time.perf_counter() - t0)
