"""Learning Q* from samples: tabular Q-learning and (tabular) fitted Q-iteration."""

from __future__ import annotations

import bisect
import random
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from taskrl.tabular.mdp import FiniteMDP

__all__ = [
    "QLearningResult",
    "FittedQResult",
    "Transitions",
    "q_learning",
    "fitted_q_iteration",
    "sample_transitions",
]


@dataclass(frozen=True, eq=False)
class QLearningResult:
    """The result of `q_learning`.

    Attributes:
        q_values: learned ``Q[s, a]``, shape ``[S, A]``.
        policy: greedy policy ``argmax_a Q[s, a]``, int ``[S]``.
        visits: number of updates of each ``(s, a)``, shape ``[S, A]``.
        episodes: episodes run.
        steps: environment steps taken.
        episode_returns: undiscounted return of each episode, ``[episodes]``.
        seconds: wall-clock time.
    """

    q_values: np.ndarray
    policy: np.ndarray
    visits: np.ndarray
    episodes: int
    steps: int
    episode_returns: np.ndarray
    seconds: float


@dataclass(frozen=True, eq=False)
class FittedQResult:
    """The result of `fitted_q_iteration`.

    Attributes:
        q_values: fitted ``Q[s, a]``, shape ``[S, A]`` (pairs absent from the data keep ``q_init``).
        policy: greedy policy, int ``[S]``.
        counts: number of samples of each ``(s, a)``, ``[S, A]``.
        iterations: regression rounds run.
        converged: whether ``max |Q_k+1 - Q_k| < tol`` was reached.
        seconds: wall-clock time.
    """

    q_values: np.ndarray
    policy: np.ndarray
    counts: np.ndarray
    iterations: int
    converged: bool
    seconds: float


@dataclass(frozen=True, eq=False)
class Transitions:
    """A dataset of transitions ``(s, a, r, s', done)`` as parallel arrays of length ``N``.

    ``done[i]`` is true when ``s'[i]`` is terminal (nothing is bootstrapped from it).
    """

    states: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    next_states: np.ndarray
    dones: np.ndarray

    def __len__(self) -> int:
        return int(self.states.shape[0])


class _Simulator:
    """Samples ``s' ~ P(.|s, a)`` from a FiniteMDP in pure Python (fast for one step at a time)."""

    def __init__(self, mdp: FiniteMDP) -> None:
        S, A = mdp.n_states, mdp.n_actions
        P = mdp.P_by_action  # [A * S, S], canonical CSR
        rewards = mdp.transition_rewards
        R = mdp.R
        self.next: list[list[int]] = []
        self.cum: list[list[float]] = []
        self.rew: list[list[float]] = []
        for s in range(S):
            for a in range(A):
                lo, hi = P.indptr[a * S + s], P.indptr[a * S + s + 1]
                self.next.append(P.indices[lo:hi].tolist())
                self.cum.append(np.cumsum(P.data[lo:hi]).tolist())
                if rewards is None:  # only expected rewards known: pay R[s, a] on every transition
                    self.rew.append([float(R[s, a])] * (hi - lo))
                else:
                    self.rew.append(rewards[lo:hi].tolist())
        self.A = A
        self.terminal = mdp.terminal.tolist()
        self.init_states = np.flatnonzero(mdp.initial).tolist()
        self.init_cum = np.cumsum(mdp.initial[mdp.initial > 0]).tolist()

    def reset(self, rng: random.Random) -> int:
        i = bisect.bisect_right(self.init_cum, rng.random() * self.init_cum[-1])
        return self.init_states[min(i, len(self.init_states) - 1)]

    def step(self, s: int, a: int, rng: random.Random) -> tuple[int, float, bool]:
        row = s * self.A + a
        cum = self.cum[row]
        # Inverse-CDF sampling; clamp guards against round-off in the last cumulative sum.
        i = min(bisect.bisect_right(cum, rng.random() * cum[-1]), len(cum) - 1)
        s2 = self.next[row][i]
        return s2, self.rew[row][i], self.terminal[s2]


class _GymSimulator:
    """Adapts a gymnasium env with discrete observations and actions to the simulator interface."""

    def __init__(self, env: Any, seed: int) -> None:
        self.env = env
        self.seed = seed
        self.first = True

    def reset(self, rng: random.Random) -> int:
        obs, _ = self.env.reset(seed=self.seed if self.first else None)
        self.first = False
        return int(obs)

    def step(self, s: int, a: int, rng: random.Random) -> tuple[int, float, bool]:
        obs, r, terminated, truncated, _ = self.env.step(a)
        self.truncated = bool(truncated)
        return int(obs), float(r), bool(terminated)


def q_learning(
    env: Any,
    *,
    episodes: int = 10_000,
    gamma: float | None = None,
    learning_rate: float = 1.0,
    lr_exponent: float = 0.8,
    epsilon: float = 0.1,
    max_steps: int = 1_000,
    q_init: float = 0.0,
    seed: int = 0,
) -> QLearningResult:
    """Tabular Q-learning (Watkins) with epsilon-greedy exploration.

    Update after each step ``(s, a, r, s', done)``::

        Q[s, a] += alpha(s, a) * (r + gamma * (1 - done) * max_a' Q[s', a'] - Q[s, a])

    with step size ``alpha(s, a) = learning_rate / n(s, a) ** lr_exponent``, where ``n(s, a)``
    counts updates of the pair. For ``0.5 < lr_exponent <= 1`` this satisfies the Robbins-Monro
    conditions, so Q converges to Q* on pairs that keep being visited; ``lr_exponent = 0`` gives
    a constant step size.

    Args:
        env: a `FiniteMDP` (simulated, episodes start from ``mdp.initial``) or a gymnasium
            environment with ``Discrete`` observation and action spaces.
        episodes: number of episodes.
        gamma: discount; defaults to ``mdp.gamma`` and is required for a gymnasium env.
        learning_rate: step-size scale.
        lr_exponent: step-size decay exponent (see above).
        epsilon: probability of a uniformly random action (ties among greedy actions are
            broken at random too, so an all-zero start still explores).
        max_steps: episode length limit; hitting it ends the episode without treating the last
            state as terminal (it is bootstrapped).
        q_init: initial value of every Q entry.
        seed: seeds the exploration, the simulator and (on the first reset) a gymnasium env.
    """
    t0 = time.perf_counter()
    rng = random.Random(seed)
    if isinstance(env, FiniteMDP):
        sim: Any = _Simulator(env)
        S, A = env.n_states, env.n_actions
        gamma = env.gamma if gamma is None else gamma
    else:
        S, A = int(env.observation_space.n), int(env.action_space.n)
        sim = _GymSimulator(env, seed)
        env.action_space.seed(seed)
        if gamma is None:
            raise ValueError("gamma is required when learning from a gymnasium env")
    if not 0.0 <= gamma <= 1.0:
        raise ValueError(f"gamma={gamma} must be in [0, 1]")
    if not 0.0 <= epsilon <= 1.0:
        raise ValueError(f"epsilon={epsilon} must be a probability in [0, 1]")
    if episodes < 0 or max_steps < 1:
        raise ValueError("episodes must be >= 0 and max_steps >= 1")
    Q = [[float(q_init)] * A for _ in range(S)]  # lists: ~10x faster than numpy for scalar access
    n = [[0] * A for _ in range(S)]
    actions = range(A)
    returns = np.zeros(episodes)
    steps = 0
    gym = isinstance(sim, _GymSimulator)
    terminal = getattr(sim, "terminal", None)
    for ep in range(episodes):
        s = sim.reset(rng)
        if terminal is not None and terminal[s]:
            continue  # started in a terminal state: nothing to learn
        total = 0.0
        for _ in range(max_steps):
            q_s = Q[s]
            if rng.random() < epsilon:
                a = rng.randrange(A)
            else:
                best = max(q_s)
                ties = [b for b in actions if q_s[b] == best]
                a = ties[0] if len(ties) == 1 else rng.choice(ties)
            s2, r, done = sim.step(s, a, rng)
            # TD target: no bootstrap from a terminal next state.
            target = r if done else r + gamma * max(Q[s2])
            n[s][a] += 1
            q_s[a] += learning_rate / n[s][a] ** lr_exponent * (target - q_s[a])
            total += r
            steps += 1
            s = s2
            if done or (gym and sim.truncated):
                break
        returns[ep] = total
    q = np.asarray(Q, dtype=np.float64)
    return QLearningResult(q, q.argmax(axis=1), np.asarray(n), episodes, steps, returns, time.perf_counter() - t0)


def sample_transitions(mdp: FiniteMDP, n: int, *, seed: int = 0) -> Transitions:
    """A generative-model dataset: ``n`` transitions from uniformly random non-terminal ``s`` and ``a``.

    Args:
        mdp: the MDP to sample from.
        n: number of transitions.
        seed: random seed.
    """
    rng = np.random.default_rng(seed)
    S, A = mdp.n_states, mdp.n_actions
    live = np.flatnonzero(~mdp.terminal)
    if live.size == 0:
        raise ValueError("the MDP has no non-terminal states to sample from")
    s = live[rng.integers(0, live.size, n)]
    a = rng.integers(0, A, n)
    P = mdp.P_by_action
    rows = a * S + s
    # Inverse-CDF sampling within each CSR row, vectorised over the whole dataset.
    cum = np.concatenate([[0.0], np.cumsum(P.data)])  # cum[j] = mass of entries before j
    lo, hi = P.indptr[rows], P.indptr[rows + 1]
    u = cum[lo] + rng.random(n) * (cum[hi] - cum[lo])
    k = np.clip(np.searchsorted(cum, u, side="right") - 1, lo, hi - 1)
    s2 = P.indices[k]
    r = mdp.transition_rewards[k] if mdp.transition_rewards is not None else mdp.R[s, a]
    return Transitions(s, a, np.asarray(r, dtype=np.float64), s2, mdp.terminal[s2].copy())


def _as_transitions(dataset: Any) -> Transitions:
    if isinstance(dataset, Transitions):
        return dataset
    if isinstance(dataset, tuple) and len(dataset) == 5 and all(isinstance(x, np.ndarray) and x.ndim == 1 for x in dataset):
        cols = dataset  # five parallel numpy arrays (a tuple of five 5-tuples is five transitions)
    else:
        rows = list(dataset)
        if rows and any(len(t) != 5 for t in rows):
            raise ValueError("dataset entries must be 5-tuples (s, a, r, s', done)")
        cols = tuple(zip(*rows)) if rows else ((), (), (), (), ())
    s, a, r, s2, d = (np.asarray(c) for c in cols)
    return Transitions(s.astype(np.int64), a.astype(np.int64), r.astype(np.float64), s2.astype(np.int64), d.astype(bool))


def fitted_q_iteration(
    dataset: Transitions | Sequence[tuple[int, int, float, int, bool]] | tuple[np.ndarray, ...],
    *,
    n_states: int,
    n_actions: int,
    gamma: float,
    tol: float = 1e-10,
    max_iterations: int = 10_000,
    q_init: float = 0.0,
) -> FittedQResult:
    """Fitted Q-iteration with a tabular regressor, on a fixed dataset of transitions.

    Each round regresses ``Q_k+1`` on the targets ``y_i = r_i + gamma * (1 - done_i) * max_a'
    Q_k(s'_i, a')``. For a lookup table the least-squares fit is the per-pair mean of the targets,

        Q_k+1(s, a) = mean_i r_i + gamma * sum_s' Phat(s'|s, a) max_a' Q_k(s', a'),

    where ``Phat`` holds the (non-terminal) empirical next-state frequencies, so a round is one
    sparse mat-vec; this is value iteration on the empirical MDP.

    Args:
        dataset: `Transitions`, a tuple of five 1-D numpy arrays ``(s, a, r, s', done)``,
            or a sequence of 5-tuples.
        n_states: number of states ``S`` (state indices must be in ``[0, S)``).
        n_actions: number of actions ``A``.
        gamma: discount factor in ``[0, 1]``.
        tol: stop when ``max |Q_k+1 - Q_k| < tol``.
        max_iterations: maximum number of regression rounds.
        q_init: initial Q, also kept for pairs absent from the dataset.
    """
    t0 = time.perf_counter()
    data = _as_transitions(dataset)
    S, A = n_states, n_actions
    for field, x, hi in (("s", data.states, S), ("a", data.actions, A), ("s'", data.next_states, S)):
        bad = x[(x < 0) | (x >= hi)]
        if bad.size:
            raise ValueError(f"dataset field {field} has value {int(bad[0])} outside [0, {hi})")
    if not np.all(np.isfinite(data.rewards)):
        raise ValueError("dataset field r has non-finite rewards")
    if not 0.0 <= gamma <= 1.0:
        raise ValueError(f"gamma={gamma} must be in [0, 1]")
    pair = data.states * A + data.actions
    counts = np.bincount(pair, minlength=S * A).astype(np.float64)
    seen = counts > 0
    inv = np.zeros_like(counts)
    inv[seen] = 1.0 / counts[seen]
    r_mean = np.bincount(pair, weights=data.rewards, minlength=S * A) * inv
    # gamma * Phat as a sparse [S * A, S] matrix; done transitions contribute no bootstrap.
    w = gamma * (~data.dones) * inv[pair]
    gP = sp.csr_matrix((w, (pair, data.next_states)), shape=(S * A, S))
    Q = np.full(S * A, float(q_init))
    delta, k = np.inf, 0
    for k in range(1, max_iterations + 1):  # noqa: B007 (k: the iterations run, reported after the loop)
        V = Q.reshape(S, A).max(axis=1)
        Q_new = np.where(seen, r_mean + gP @ V, Q)  # unseen pairs keep their initial value
        delta = float(np.abs(Q_new - Q).max(initial=0.0))
        Q = Q_new
        if delta < tol:
            break
    q = Q.reshape(S, A)
    return FittedQResult(
        q, q.argmax(axis=1), counts.reshape(S, A).astype(np.int64), k, bool(delta < tol), time.perf_counter() - t0
    )
