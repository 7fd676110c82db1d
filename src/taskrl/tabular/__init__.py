"""Exact dynamic programming and tabular learning on finite MDPs (numpy/scipy only).

Quick start::

    from taskrl.tabular import drummer, policy_iteration, q_values, constant_policy, WATCH
    mdp = drummer()
    sol = policy_iteration(mdp)            # V*, Q*, optimal policy
    Q_watch = q_values(mdp, constant_policy(mdp, WATCH))
"""

from taskrl.tabular.dp import (
    PolicyEvaluation,
    Solution,
    advantages,
    bellman_backup,
    evaluate_policy,
    evaluate_policy_iterative,
    greedy_policy,
    policy_improvement,
    policy_iteration,
    q_values,
    value_iteration,
)
from taskrl.tabular.examples import CHILL, DEFAULT_GRID, PRACTISE, WATCH, drummer, drummer_state, grid_world
from taskrl.tabular.learning import (
    FittedQResult,
    QLearningResult,
    Transitions,
    fitted_q_iteration,
    q_learning,
    sample_transitions,
)
from taskrl.tabular.mdp import FiniteMDP, GridLayout
from taskrl.tabular.policies import (
    as_stochastic,
    check_policy,
    constant_policy,
    policy_chain,
    proper_policy,
    uniform_policy,
)
from taskrl.tabular.render import render_grid
from taskrl.tabular.toytext import mdp_from_gymnasium

__all__ = [
    "mdp_from_gymnasium",
    "FiniteMDP",
    "GridLayout",
    "Solution",
    "PolicyEvaluation",
    "QLearningResult",
    "FittedQResult",
    "Transitions",
    "bellman_backup",
    "evaluate_policy",
    "evaluate_policy_iterative",
    "q_values",
    "advantages",
    "greedy_policy",
    "policy_improvement",
    "policy_iteration",
    "value_iteration",
    "q_learning",
    "fitted_q_iteration",
    "sample_transitions",
    "check_policy",
    "as_stochastic",
    "uniform_policy",
    "constant_policy",
    "proper_policy",
    "policy_chain",
    "drummer",
    "drummer_state",
    "grid_world",
    "render_grid",
    "CHILL",
    "WATCH",
    "PRACTISE",
    "DEFAULT_GRID",
]
