"""Built-in example MDPs: the drummer and a configurable grid world."""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from taskrl.tabular.mdp import FiniteMDP, GridLayout

__all__ = ["drummer", "drummer_state", "CHILL", "WATCH", "PRACTISE", "grid_world", "DEFAULT_GRID"]

CHILL, WATCH, PRACTISE = 0, 1, 2


def drummer_state(day: int, skill: int, *, max_skill: int = 10) -> int:
    """Index of the drummer state ``(day, skill)`` for an MDP built with the same ``max_skill``."""
    return day * (max_skill + 1) + skill


def drummer(
    *,
    days: int = 30,
    max_skill: int = 10,
    p_watch: float = 0.15,
    p_practise: float = 0.3,
    p_forget: float = 0.1,
    pass_probability: Sequence[float] | None = None,
    initial_skill: int = 0,
    gamma: float = 1.0,
) -> FiniteMDP:
    """The drummer: a learner has ``days`` days before a drumming test.

    State: ``(day, skill)`` with ``day in 0..days-1`` and ``skill in 0..max_skill``, index
    ``day * (max_skill + 1) + skill`` (see `drummer_state`), plus two terminal states
    ``passed`` and ``failed``. The start state ``s0`` is ``(0, initial_skill)``.

    Each day the learner picks one action; skill then changes by at most one level:

    * ``chill`` (0): skill drops by one with probability ``p_forget`` (never below 0), else stays.
    * ``watch`` (1) others drum: skill rises by one with probability ``p_watch`` (never above
      ``max_skill``), else stays.
    * ``practise`` (2): skill rises by one with probability ``p_practise``, else stays.

    After the action of the last day the test is taken with the new skill ``k``: it is passed
    with probability ``pass_probability[k]`` (default ``k / max_skill``), giving reward 1 and
    moving to ``passed``; otherwise reward 0 and ``failed``. All other rewards are 0, so with the
    default ``gamma = 1`` the value of a state is the probability of passing the test from it.

    The issue's relations (``Q(s0, chill) < V_watch(s0) < Q(s0, practise)`` for always-watch,
    greedy improvement of always-chill picks an action of positive advantage, practise optimal at
    ``s0``) hold whenever ``0 <= p_forget < 1``, ``0 < p_watch < p_practise < 1`` and
    ``pass_probability`` is strictly increasing: practising stochastically dominates watching,
    which dominates chilling, and values strictly increase with skill. Numerically they are
    clearly visible while the month is too short to master the drums for sure, say
    ``days * p_practise <= max_skill`` (otherwise the value gaps shrink towards round-off).

    Args:
        days: horizon; number of decisions before the test.
        max_skill: highest skill level ``K`` (levels ``0..K``).
        p_watch: daily probability that watching raises skill by one.
        p_practise: daily probability that practising raises skill by one.
        p_forget: daily probability that chilling lowers skill by one.
        pass_probability: probability of passing at each skill level, length ``K + 1``,
            non-decreasing in ``[0, 1]``; default ``k / K``.
        initial_skill: skill on day 0.
        gamma: discount per day (1 by default: the horizon is encoded in the state).
    """
    if days < 1:
        raise ValueError(f"days={days} must be >= 1")
    if max_skill < 1:
        raise ValueError(f"max_skill={max_skill} must be >= 1")
    for field, p in (("p_watch", p_watch), ("p_practise", p_practise), ("p_forget", p_forget)):
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"{field}={p} must be a probability in [0, 1]")
    if not 0 <= initial_skill <= max_skill:
        raise ValueError(f"initial_skill={initial_skill} must be in [0, {max_skill}]")
    K = max_skill
    if pass_probability is None:
        pass_p = np.arange(K + 1) / K
    else:
        pass_p = np.asarray(pass_probability, dtype=np.float64)
        if pass_p.shape != (K + 1,):
            raise ValueError(f"pass_probability has {pass_p.size} entries; expected max_skill + 1 = {K + 1}")
        if (pass_p < 0).any() or (pass_p > 1).any() or (np.diff(pass_p) < 0).any():
            raise ValueError("pass_probability must be non-decreasing probabilities in [0, 1]")

    n_live = days * (K + 1)
    PASSED, FAILED = n_live, n_live + 1
    S, A = n_live + 2, 3
    P = np.zeros((S, A, S))
    R = np.zeros((S, A, S))
    up = {WATCH: p_watch, PRACTISE: p_practise}
    for day in range(days):
        for k in range(K + 1):
            s = day * (K + 1) + k
            for a in (CHILL, WATCH, PRACTISE):
                if a == CHILL:
                    moves = ((max(k - 1, 0), p_forget), (k, 1.0 - p_forget))
                else:
                    moves = ((min(k + 1, K), up[a]), (k, 1.0 - up[a]))
                for k2, p in moves:  # at the skill bounds both moves land on k (summed below)
                    if p == 0.0:
                        continue
                    if day + 1 < days:
                        P[s, a, (day + 1) * (K + 1) + k2] += p
                    else:  # the test: pass with probability pass_p[k2]
                        P[s, a, PASSED] += p * pass_p[k2]
                        P[s, a, FAILED] += p * (1.0 - pass_p[k2])
                        R[s, a, PASSED] = 1.0
    # Terminal states absorb (their rows are ignored by the algorithms, but keep them stochastic).
    P[PASSED, :, PASSED] = 1.0
    P[FAILED, :, FAILED] = 1.0
    initial = np.zeros(S)
    initial[initial_skill] = 1.0
    names = [f"day {d}, skill {k}" for d in range(days) for k in range(K + 1)] + ["passed", "failed"]
    return FiniteMDP(
        P,
        R,
        gamma,
        terminal=[PASSED, FAILED],
        initial=initial,
        name="drummer",
        state_names=names,
        action_names=("chill", "watch", "practise"),
    )


#: Default grid world: start S, goal G (+1), hole H (-1), walls #.
DEFAULT_GRID = (
    "S...#",
    ".#..H",
    ".#...",
    "...#.",
    "H...G",
)

_MOVES = ((-1, 0), (0, 1), (1, 0), (0, -1))  # up, right, down, left


def grid_world(
    size: tuple[int, int] | None = None,
    *,
    layout: Sequence[str] | None = None,
    walls: Iterable[tuple[int, int]] = (),
    goals: Iterable[tuple[int, int]] | None = None,
    holes: Iterable[tuple[int, int]] = (),
    start: tuple[int, int] = (0, 0),
    slip: float = 0.1,
    step_reward: float = 0.0,
    goal_reward: float = 1.0,
    hole_reward: float = -1.0,
    gamma: float = 0.95,
) -> FiniteMDP:
    """A grid world with walls, goal cells and holes, and slippery moves.

    Give either a ``layout`` (strings of ``.`` free, ``S`` start, ``#`` wall, ``G`` goal,
    ``H`` hole) or a ``size`` plus cell lists; with neither, `DEFAULT_GRID` is used. Every
    non-wall cell is a state (row-major order). Actions are up, right, down, left (0..3). A move
    goes in the intended direction with probability ``1 - slip`` and to each perpendicular
    direction with ``slip / 2``; moving off the grid or into a wall leaves the agent in place.
    Goals and holes are terminal; entering one pays ``goal_reward`` or ``hole_reward``, any other
    step pays ``step_reward``.

    Args:
        size: ``(rows, cols)`` of an open grid built from ``walls``, ``goals``, ``holes``, ``start``.
        layout: the map as strings (overrides ``size`` and the cell lists).
        walls: wall cells ``(row, col)``.
        goals: goal cells; default the bottom-right corner.
        holes: hole cells.
        start: start cell; the initial-state distribution puts all mass there.
        slip: probability of slipping sideways, in ``[0, 1]``.
        step_reward: reward of a step that does not enter a goal or hole.
        goal_reward: reward for entering a goal.
        hole_reward: reward for entering a hole.
        gamma: discount factor.
    """
    if not 0.0 <= slip <= 1.0:
        raise ValueError(f"slip={slip} must be a probability in [0, 1]")
    if layout is None:
        if size is None:
            layout = DEFAULT_GRID
        else:
            n_rows, n_cols = size
            if n_rows < 1 or n_cols < 1:
                raise ValueError(f"size={size} must have at least one row and one column")
            cells = [["."] * n_cols for _ in range(n_rows)]
            goals = [(n_rows - 1, n_cols - 1)] if goals is None else list(goals)
            for char, group in (("#", walls), ("H", holes), ("G", goals), ("S", [start])):
                for r, c in group:
                    if not (0 <= r < n_rows and 0 <= c < n_cols):
                        raise ValueError(f"cell {(r, c)} is outside the {n_rows}x{n_cols} grid")
                    cells[r][c] = char
            layout = ["".join(row) for row in cells]
    rows = tuple(layout)
    if not rows or any(len(r) != len(rows[0]) for r in rows):
        raise ValueError("layout rows must be non-empty strings of equal length")
    bad = set("".join(rows)) - set(".S#GH")
    if bad:
        raise ValueError(f"layout has unknown cell characters {sorted(bad)}; allowed: . S # G H")
    n_rows, n_cols = len(rows), len(rows[0])
    state_of = {}
    for r in range(n_rows):
        for c in range(n_cols):
            if rows[r][c] != "#":
                state_of[(r, c)] = len(state_of)
    if not state_of:
        raise ValueError("layout has no free cells")
    starts = [rc for rc, s in state_of.items() if rows[rc[0]][rc[1]] == "S"]
    start_cell = starts[0] if starts else next(iter(state_of))
    S, A = len(state_of), 4
    P = np.zeros((S, A, S))
    R = np.zeros((S, A, S))
    terminal = np.zeros(S, dtype=bool)
    cells = list(state_of)  # cells[s] = (row, col)
    for (r, c), s in state_of.items():
        terminal[s] = rows[r][c] in "GH"

    def target(r: int, c: int, move: tuple[int, int]) -> int:
        r2, c2 = r + move[0], c + move[1]
        return state_of.get((r2, c2), state_of[(r, c)])  # walls and edges: stay

    for (r, c), s in state_of.items():
        for a in range(A):
            outcomes = ((a, 1.0 - slip), ((a + 1) % 4, slip / 2), ((a + 3) % 4, slip / 2))
            for direction, p in outcomes:
                if p > 0:
                    P[s, a, target(r, c, _MOVES[direction])] += p
            for s2 in np.flatnonzero(P[s, a]):
                r2, c2 = cells[s2]
                cell = rows[r2][c2]
                R[s, a, s2] = goal_reward if cell == "G" else hole_reward if cell == "H" else step_reward
    positions = np.array(cells, dtype=np.int64)
    initial = np.zeros(S)
    initial[state_of[start_cell]] = 1.0
    return FiniteMDP(
        P,
        R,
        gamma,
        terminal=terminal,
        initial=initial,
        name="gridworld",
        state_names=[f"({r},{c})" for r, c in state_of],
        action_names=("up", "right", "down", "left"),
        grid=GridLayout(rows, positions, ("↑", "→", "↓", "←")),
    )
