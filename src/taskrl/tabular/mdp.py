"""Finite MDPs: a validated transition matrix, expected rewards, a discount and terminal states.

Conventions (every algorithm in [`taskrl.tabular`][taskrl.tabular] follows them):

* ``P`` is given either dense, as a ``[S, A, S]`` array ``P[s, a, s']``, or sparse, as a
  ``scipy.sparse`` matrix of shape ``[S * A, S]`` whose row ``s * A + a`` is ``P(. | s, a)``.
* Rewards are given as expected rewards ``R[s, a]`` or per transition ``R[s, a, s']``; the
  latter is reduced once to ``R[s, a] = sum_s' P[s, a, s'] R[s, a, s']`` (and kept for sampling).
* **Terminal states absorb with zero reward**: ``V(s) = Q(s, a) = 0`` for a terminal ``s``.
  The reward of the transition *into* a terminal state is still collected, but nothing is
  bootstrapped from it. The rows of ``P`` for terminal states are therefore ignored (they may
  be all zero).
* Internally the Bellman backup uses the *action-major* matrix ``gamma * P`` of shape
  ``[A * S, S]`` (row ``a * S + s``), with terminal rows and columns zeroed. One sweep is then a
  single sparse mat-vec giving ``Q`` as ``[A, S]``, whose max over actions is an elementwise
  maximum of ``A`` contiguous vectors -- about 10x cheaper than ``Q.max(axis=1)`` on ``[S, A]``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import scipy.sparse as sp

__all__ = ["FiniteMDP", "GridLayout"]


@dataclass(frozen=True, eq=False)
class GridLayout:
    """Where the states of a grid-world-like MDP sit on a 2-D map, for rendering.

    Args:
        rows: the map, one string per grid row (e.g. ``"S.#G"``). ``#`` is a wall; any character
            other than ``.``, ``S`` and ``F`` marks a special cell (goal ``G``, hole ``H``, cliff
            ``C``) that is drawn as itself instead of as a policy arrow.
        positions: ``[S, 2]`` int array, the ``(row, col)`` of each state, ``(-1, -1)`` when a
            state has no cell.
        arrows: one glyph per action, used to draw a policy (e.g. ``("↑", "→", "↓", "←")``).
    """

    rows: tuple[str, ...]
    positions: np.ndarray
    arrows: tuple[str, ...]


def _as_mask(terminal: Any, n_states: int) -> np.ndarray:
    """A boolean ``[S]`` mask from a mask or from a list of state indices."""
    if terminal is None:
        return np.zeros(n_states, dtype=bool)
    arr = np.asarray(terminal)
    if arr.dtype == bool:
        if arr.shape != (n_states,):
            raise ValueError(f"terminal mask has shape {arr.shape}; expected ({n_states},) booleans")
        return arr.copy()
    arr = arr.astype(np.int64).ravel()
    bad = arr[(arr < 0) | (arr >= n_states)]
    if bad.size:
        raise ValueError(f"terminal state {int(bad[0])} is not a state index in [0, {n_states})")
    mask = np.zeros(n_states, dtype=bool)
    mask[arr] = True
    return mask


class FiniteMDP:
    """A finite Markov decision process, validated on construction.

    Args:
        P: transition probabilities, dense ``[S, A, S]`` or sparse ``[S * A, S]`` (row
            ``s * A + a``). Entries must be finite and non-negative, and each row ``P[s, a]`` of a
            non-terminal state must sum to 1 (within ``atol``).
        R: rewards, ``[S, A]`` (expected reward of taking ``a`` in ``s``) or ``[S, A, S]`` (reward
            of the transition ``s, a -> s'``; dense, or sparse ``[S * A, S]``).
        gamma: discount factor, ``0 <= gamma < 1``; ``gamma = 1`` is allowed only when there are
            terminal states (episodic problems).
        terminal: boolean mask ``[S]`` or a list of terminal state indices. Terminal states
            absorb with zero reward (their values are 0).
        initial: initial-state distribution ``[S]``; defaults to uniform over non-terminal states.
        name: a label used in printouts.
        state_names: optional label per state.
        action_names: optional label per action.
        grid: optional `GridLayout` used to draw policies and values as a map.
        atol: tolerance for the row-sum checks.

    Raises:
        ValueError: naming the offending field when the MDP is malformed.
    """

    def __init__(
        self,
        P: Any,
        R: Any,
        gamma: float,
        terminal: Any = None,
        initial: Any = None,
        *,
        name: str = "mdp",
        state_names: Sequence[str] | None = None,
        action_names: Sequence[str] | None = None,
        grid: GridLayout | None = None,
        atol: float = 1e-8,
    ) -> None:
        P_sm, n_states, n_actions = self._check_P(P)
        S, A = n_states, n_actions
        self.name = name
        self.n_states, self.n_actions = S, A
        self.terminal = _as_mask(terminal, S)
        self.terminal.flags.writeable = False
        self._check_rows(P_sm, atol)

        gamma = float(gamma)
        if not np.isfinite(gamma) or gamma < 0.0 or gamma > 1.0:
            raise ValueError(
                f"gamma={gamma} is outside [0, 1); the discount must satisfy 0 <= gamma < 1 (gamma = 1 only with terminal states)"
            )
        if gamma == 1.0 and not self.terminal.any():
            raise ValueError(
                "gamma=1 needs terminal states but the terminal mask is empty: undiscounted "
                "returns of a never-ending MDP are infinite; use gamma < 1 or mark terminal states"
            )
        self.gamma = gamma

        # Row permutation from state-major (s * A + a) to action-major (a * S + s).
        to_action_major = (np.arange(S)[None, :] * A + np.arange(A)[:, None]).ravel()
        P_am = P_sm[to_action_major].tocsr()
        P_am.sort_indices()
        self._P_am = P_am

        # Expected rewards R[s, a]; per-transition rewards (aligned with P_am.data) if given.
        self.R, self._transition_rewards = self._reduce_rewards(R, P_am, S, A)
        self.R.flags.writeable = False

        if initial is None:
            live = ~self.terminal if (~self.terminal).any() else np.ones(S, dtype=bool)
            initial = live / live.sum()
        initial = np.asarray(initial, dtype=np.float64)
        if initial.shape != (S,):
            raise ValueError(f"initial distribution has shape {initial.shape}; expected ({S},)")
        if not np.all(np.isfinite(initial)) or (initial < 0).any():
            raise ValueError("initial distribution has negative or non-finite entries")
        if abs(initial.sum() - 1.0) > atol * S + 1e-12:
            raise ValueError(f"initial distribution sums to {initial.sum():.6g}; it must sum to 1")
        self.initial = initial
        self.initial.flags.writeable = False

        if state_names is not None and len(state_names) != S:
            raise ValueError(f"state_names has {len(state_names)} entries; expected {S}")
        if action_names is not None and len(action_names) != A:
            raise ValueError(f"action_names has {len(action_names)} entries; expected {A}")
        self.state_names = tuple(state_names) if state_names is not None else tuple(map(str, range(S)))
        self.action_names = tuple(action_names) if action_names is not None else tuple(map(str, range(A)))
        if grid is not None and grid.positions.shape != (S, 2):
            raise ValueError(f"grid.positions has shape {grid.positions.shape}; expected ({S}, 2)")
        self.grid = grid

    # ------------------------------------------------------------------ validation helpers
    @staticmethod
    def _check_P(P: Any) -> tuple[sp.csr_matrix, int, int]:
        """Return ``P`` as a canonical state-major CSR ``[S * A, S]`` plus ``S`` and ``A``."""
        if sp.issparse(P):
            P = sp.csr_matrix(P, dtype=np.float64)
            rows, S = P.shape
            if S < 1 or rows % S != 0 or rows == 0:
                raise ValueError(f"P has shape {P.shape}; sparse P must have shape [S * A, S] (row s * A + a holds P(. | s, a))")
            A = rows // S
        else:
            P = np.asarray(P, dtype=np.float64)
            if P.ndim != 3 or P.shape[0] != P.shape[2] or P.shape[1] < 1:
                raise ValueError(
                    f"P has shape {P.shape}; dense P must have shape [S, A, S] "
                    "(or pass a scipy.sparse matrix of shape [S * A, S])"
                )
            S, A = P.shape[0], P.shape[1]
            P = sp.csr_matrix(P.reshape(S * A, S))
        if S < 1:
            raise ValueError("P describes an MDP with no states")
        P.sum_duplicates()
        if not np.all(np.isfinite(P.data)):
            r = int(np.searchsorted(P.indptr, np.flatnonzero(~np.isfinite(P.data))[0], side="right") - 1)
            raise ValueError(f"P[s={r // A}, a={r % A}] has a non-finite entry; probabilities must be finite")
        neg = np.flatnonzero(P.data < 0)
        if neg.size:
            k = int(neg[0])
            r = int(np.searchsorted(P.indptr, k, side="right") - 1)
            raise ValueError(
                f"P[s={r // A}, a={r % A}, s'={int(P.indices[k])}] = {P.data[k]:.6g} is negative; probabilities must be >= 0"
            )
        P.eliminate_zeros()
        return P, S, A

    def _check_rows(self, P_sm: sp.csr_matrix, atol: float) -> None:
        A = self.n_actions
        sums = np.asarray(P_sm.sum(axis=1)).ravel()
        state_of_row = np.arange(P_sm.shape[0]) // A
        ok = np.abs(sums - 1.0) <= atol
        # Terminal states' rows are never used, so an empty row is fine there.
        ok |= self.terminal[state_of_row] & (np.abs(sums) <= atol)
        if not ok.all():
            r = int(np.flatnonzero(~ok)[0])
            raise ValueError(f"P[s={r // A}, a={r % A}] sums to {sums[r]:.6g}; each row of P must sum to 1")

    def _reduce_rewards(self, R: Any, P_am: sp.csr_matrix, S: int, A: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Expected rewards ``[S, A]`` and, for ``R[s, a, s']``, the reward of each stored transition."""
        am_rows = np.repeat(np.arange(A * S), np.diff(P_am.indptr))
        cols = P_am.indices
        if sp.issparse(R):
            R = sp.csr_matrix(R)
            if R.shape != (S * A, S):
                raise ValueError(f"sparse R has shape {R.shape}; expected [S * A, S] = ({S * A}, {S})")
            sm_rows = (am_rows % S) * A + am_rows // S
            r_sas = np.asarray(R[sm_rows, cols]).ravel().astype(np.float64)
        else:
            R = np.asarray(R, dtype=np.float64)
            if R.shape == (S, A):
                if not np.all(np.isfinite(R)):
                    raise ValueError("R has non-finite entries; rewards must be finite")
                return R.copy(), None
            if R.shape == (S * A, S):
                R = R.reshape(S, A, S)
            if R.shape != (S, A, S):
                raise ValueError(
                    f"R has shape {R.shape} but P implies (S, A) = ({S}, {A}); R must be "
                    f"[S, A] = ({S}, {A}) or [S, A, S] = ({S}, {A}, {S})"
                )
            r_sas = R[am_rows % S, am_rows // S, cols]
        if not np.all(np.isfinite(r_sas)):
            raise ValueError("R has non-finite entries; rewards must be finite")
        expected_am = np.bincount(am_rows, weights=P_am.data * r_sas, minlength=A * S)
        return expected_am.reshape(A, S).T.copy(), r_sas

    # ------------------------------------------------------------------ derived views
    @cached_property
    def P(self) -> sp.csr_matrix:
        """Transition matrix in the public state-major layout, CSR ``[S * A, S]`` (row ``s * A + a``)."""
        S, A = self.n_states, self.n_actions
        to_state_major = (np.arange(A)[None, :] * S + np.arange(S)[:, None]).ravel()
        return self._P_am[to_state_major].tocsr()

    @property
    def P_by_action(self) -> sp.csr_matrix:
        """Transition matrix in action-major layout, CSR ``[A * S, S]`` (row ``a * S + s``)."""
        return self._P_am

    def transition_tensor(self) -> np.ndarray:
        """Dense ``P[s, a, s']`` (only sensible for small MDPs)."""
        S, A = self.n_states, self.n_actions
        return self._P_am.toarray().reshape(A, S, S).transpose(1, 0, 2).copy()

    @cached_property
    def discounted_transitions(self) -> sp.csr_matrix:
        """``gamma * P`` action-major ``[A * S, S]`` with terminal rows and columns zeroed.

        ``Q = rewards_by_action + (discounted_transitions @ V).reshape(A, S)`` is the Bellman
        backup under the terminal-state convention, for any ``V``.
        """
        S = self.n_states
        M = self._P_am.copy()
        live = (~self.terminal).astype(np.float64)
        rows = np.repeat(np.arange(M.shape[0]), np.diff(M.indptr))
        # Zero columns of terminal s' (no bootstrap) and rows of terminal s (they absorb).
        M.data *= self.gamma * live[M.indices] * live[rows % S]
        M.eliminate_zeros()
        return M

    @cached_property
    def rewards_by_action(self) -> np.ndarray:
        """Expected rewards as ``[A, S]``, zero for terminal states (they absorb with no reward)."""
        Rt = np.array(self.R.T, order="C")  # a copy: R itself is read-only
        Rt[:, self.terminal] = 0.0
        Rt.flags.writeable = False
        return Rt

    @property
    def transition_rewards(self) -> np.ndarray | None:
        """Reward of each stored transition, aligned with ``P_by_action.data`` (``None`` if R was ``[S, A]``)."""
        return self._transition_rewards

    def __repr__(self) -> str:
        return (
            f"FiniteMDP(name={self.name!r}, states={self.n_states}, actions={self.n_actions}, "
            f"gamma={self.gamma}, terminal={int(self.terminal.sum())}, nnz={self._P_am.nnz})"
        )
