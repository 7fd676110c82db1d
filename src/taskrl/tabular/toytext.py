"""Read the transition table of a gymnasium toy-text environment into a `FiniteMDP`."""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from taskrl.tabular.mdp import FiniteMDP, GridLayout

__all__ = ["mdp_from_gymnasium", "TOY_TEXT_ENVS"]

#: Environment ids accepted by the CLI (gymnasium 1.x names).
TOY_TEXT_ENVS = ("FrozenLake-v1", "FrozenLake8x8-v1", "CliffWalking-v1", "Taxi-v4")


def _layout(env: Any, n_states: int) -> tuple[GridLayout | None, tuple[str, ...] | None, list[str] | None]:
    """Map layout, action names and state names for the known toy-text environments."""
    kind = type(env).__name__
    if kind == "FrozenLakeEnv":
        rows = tuple(b"".join(r).decode() for r in env.desc)
        ncol = len(rows[0])
        pos = np.stack([np.arange(n_states) // ncol, np.arange(n_states) % ncol], axis=1)
        names = [f"{s} ({r},{c})" for s, (r, c) in enumerate(pos)]
        return GridLayout(rows, pos, ("←", "↓", "→", "↑")), ("left", "down", "right", "up"), names
    if kind == "CliffWalkingEnv":
        nrow, ncol = env.shape
        grid = [["."] * ncol for _ in range(nrow)]
        for r, c in zip(*np.nonzero(env._cliff)):
            grid[r][c] = "C"
        grid[nrow - 1][0], grid[nrow - 1][ncol - 1] = "S", "G"
        pos = np.stack([np.arange(n_states) // ncol, np.arange(n_states) % ncol], axis=1)
        rows = tuple("".join(r) for r in grid)
        names = [f"{s} ({r},{c})" for s, (r, c) in enumerate(pos)]
        return GridLayout(rows, pos, ("↑", "→", "↓", "←")), ("up", "right", "down", "left"), names
    if kind == "TaxiEnv":
        depots = "RGYB"
        names = []
        for s in range(n_states):
            r, c, p, d = env.decode(s)
            where = "in taxi" if p == 4 else f"at {depots[p]}"
            names.append(f"{s} taxi ({r},{c}), passenger {where}, to {depots[d]}")
        return None, ("south", "north", "east", "west", "pickup", "dropoff"), names
    return None, None, None


def mdp_from_gymnasium(env: Any, gamma: float = 0.99, **make_kwargs: Any) -> FiniteMDP:
    """The `FiniteMDP` of a gymnasium toy-text environment's transition table ``env.P``.

    Works for any environment whose unwrapped form has ``P[s][a] = [(prob, s', reward, terminated), ...]``
    (FrozenLake, CliffWalking, Taxi). States entered with ``terminated=True`` become terminal states.

    Args:
        env: a gymnasium environment (wrapped or not) or an environment id such as ``"FrozenLake-v1"``.
        gamma: discount factor of the resulting MDP.
        **make_kwargs: forwarded to ``gymnasium.make`` when ``env`` is an id.
    """
    name = None
    if isinstance(env, str):
        import gymnasium as gym

        name = env
        env = gym.make(env, **make_kwargs)
    base = getattr(env, "unwrapped", env)
    table = getattr(base, "P", None)
    if not isinstance(table, dict):
        raise ValueError(
            f"env {type(base).__name__} has no transition table P[s][a] = [(prob, s', r, done)]; "
            "only toy-text environments such as FrozenLake, CliffWalking and Taxi have one"
        )
    S = len(table)
    A = len(table[0])
    rows, cols, probs, rewards, done_to = [], [], [], [], []
    for s in range(S):
        for a in range(A):
            for prob, s2, r, done in table[s][a]:
                rows.append(s * A + a)
                cols.append(int(s2))
                probs.append(float(prob))
                rewards.append(float(r))
                done_to.append((s, int(s2), bool(done)))
    rows_a, cols_a = np.asarray(rows), np.asarray(cols)
    probs_a, rewards_a = np.asarray(probs), np.asarray(rewards)

    # A state is terminal when some transition enters it with terminated=True. gymnasium encodes
    # termination per transition, so check that, from every live state reachable from the
    # initial distribution, entering such a state always terminates; otherwise a per-state mask
    # could not represent the environment. (Taxi has unreachable states, e.g. passenger already
    # at the destination, whose transitions disagree; their values are not meaningful.)
    terminal = np.zeros(S, dtype=bool)
    for _, s2, done in done_to:
        if done:
            terminal[s2] = True
    init = getattr(base, "initial_state_distrib", None)
    succ: list[list[tuple[int, bool]]] = [[] for _ in range(S)]
    for s, s2, done in done_to:
        succ[s].append((s2, done))
    frontier = list(np.flatnonzero(np.asarray(init) > 0)) if init is not None else list(range(S))
    seen = np.zeros(S, dtype=bool)
    seen[frontier] = True
    while frontier:
        s = int(frontier.pop())
        if terminal[s]:
            continue
        for s2, done in succ[s]:
            if terminal[s2] != done:
                raise ValueError(
                    f"env transition {s} -> {s2} has terminated={done} but other transitions into "
                    f"state {s2} disagree; termination must depend on the next state only"
                )
            if not seen[s2]:
                seen[s2] = True
                frontier.append(s2)

    # Duplicate (s, a, s') entries (FrozenLake's slips into walls) are summed; the reward of the
    # merged entry is the probability-weighted mean so that the expected reward is unchanged.
    P = sp.coo_matrix((probs_a, (rows_a, cols_a)), shape=(S * A, S)).tocsr()
    PR = sp.coo_matrix((probs_a * rewards_a, (rows_a, cols_a)), shape=(S * A, S)).tocsr()
    P.sum_duplicates()
    PR.sum_duplicates()
    R_sas = PR.copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        # Same sparsity pattern as P, so the data arrays align after canonicalisation.
        R_sas.data = np.where(P.data > 0, PR.data / np.where(P.data > 0, P.data, 1.0), 0.0)

    grid, action_names, state_names = _layout(base, S)
    spec = getattr(env, "spec", None)
    return FiniteMDP(
        P,
        R_sas,
        gamma,
        terminal=terminal,
        initial=None if init is None else np.asarray(init, dtype=np.float64),
        name=name or (spec.id if spec is not None else type(base).__name__),
        action_names=action_names,
        state_names=state_names,
        grid=grid,
    )
