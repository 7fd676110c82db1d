"""Text rendering of policies and values on grid-world maps."""

from __future__ import annotations

import numpy as np

from taskrl.tabular.mdp import FiniteMDP

__all__ = ["render_grid"]

_FREE = ".SF"  # cells drawn as the policy's arrow; any other character is drawn as itself
_WALL = "█"


def render_grid(mdp: FiniteMDP, policy: np.ndarray | None = None, values: np.ndarray | None = None) -> list[str]:
    """Draw a policy (arrows) or values (numbers) on the MDP's map, one string per grid row.

    Args:
        mdp: an MDP with a [`GridLayout`][taskrl.tabular.mdp.GridLayout] (``mdp.grid``).
        policy: deterministic ``[S]`` or stochastic ``[S, A]`` policy (drawn by its most likely
            action); special cells (goal, hole, cliff) and terminal states show their map letter.
        values: ``[S]`` values, drawn with two decimals instead of arrows.
    """
    if mdp.grid is None:
        raise ValueError(f"{mdp.name} has no grid layout to render")
    if (policy is None) == (values is None):
        raise ValueError("pass exactly one of policy or values")
    layout = mdp.grid
    if policy is not None:
        policy = np.asarray(policy)
        actions = policy.argmax(axis=1) if policy.ndim == 2 else policy
    width = 1 if values is None else max(len(f"{v:.2f}") for v in np.asarray(values))
    cells = [[(_WALL if ch == "#" else ch).rjust(width) for ch in row] for row in layout.rows]
    for s, (r, c) in enumerate(layout.positions):
        if r < 0:
            continue
        ch = layout.rows[r][c]
        if values is not None:
            cells[r][c] = f"{values[s]:.2f}".rjust(width)
        elif ch in _FREE and not mdp.terminal[s]:
            cells[r][c] = layout.arrows[int(actions[s])]
    return [" ".join(row) for row in cells]
