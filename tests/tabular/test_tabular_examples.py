"""The drummer relations from the issue, and the grid world."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from taskrl.tabular import (
    CHILL,
    PRACTISE,
    WATCH,
    advantages,
    constant_policy,
    drummer,
    drummer_state,
    evaluate_policy,
    grid_world,
    policy_improvement,
    policy_iteration,
    q_values,
    render_grid,
    value_iteration,
)


def check_drummer_relations(mdp, s0):
    # Always watch: Q(s0, watch) = V(s0), and chill < V < practise at s0.
    watch = constant_policy(mdp, WATCH)
    V = evaluate_policy(mdp, watch)
    Q = q_values(mdp, watch)
    A = advantages(mdp, watch)
    assert Q[s0, WATCH] == pytest.approx(V[s0], abs=1e-12)
    assert Q[s0, CHILL] < V[s0] < Q[s0, PRACTISE]
    assert A[s0, PRACTISE] > 0 > A[s0, CHILL]

    # Always chill: greedy improvement picks an action with positive advantage at s0, and the
    # improved policy is at least as good everywhere (policy improvement theorem).
    chill = constant_policy(mdp, CHILL)
    A_chill = advantages(mdp, chill)
    improved = policy_improvement(mdp, chill)
    assert improved[s0] != CHILL
    assert A_chill[s0, improved[s0]] > 0
    changed = improved != chill
    assert (A_chill[changed, improved[changed]] > 0).all()
    assert (evaluate_policy(mdp, improved) >= evaluate_policy(mdp, chill) - 1e-12).all()

    # Optimal policy: practise is best at s0 and V*(s0) = Q*(s0, practise).
    sol = policy_iteration(mdp)
    assert sol.converged
    assert sol.policy[s0] == PRACTISE
    assert int(np.argmax(sol.q_values[s0])) == PRACTISE
    # V* solves a linear system, Q* = r + P V* is one more product: they agree to round-off (1e-12 measured at 39 days)
    assert sol.values[s0] == pytest.approx(sol.q_values[s0, PRACTISE], abs=1e-9)
    assert sol.q_values[s0, PRACTISE] > max(sol.q_values[s0, CHILL], sol.q_values[s0, WATCH])
    return V, sol


def test_drummer_relations_with_default_parameters():
    mdp = drummer()
    s0 = drummer_state(0, 0)
    assert mdp.initial[s0] == 1.0
    V_watch, sol = check_drummer_relations(mdp, s0)
    # Values are pass probabilities (gamma = 1, reward 1 for passing).
    assert 0.0 < V_watch[s0] < sol.values[s0] < 1.0
    # Independent check of V_watch(s0): final skill ~ min(Binomial(30, 0.15), 10), pass with k/10.
    from scipy.stats import binom

    k = np.arange(31)
    expected = (binom.pmf(k, 30, 0.15) * np.minimum(k, 10) / 10).sum()
    assert V_watch[s0] == pytest.approx(expected, abs=1e-12)
    # Value iteration agrees, in exactly `days` + 1 sweeps (finite horizon).
    vi = value_iteration(mdp, tol=1e-12)
    np.testing.assert_allclose(vi.values, sol.values, atol=1e-12)
    assert vi.iterations == 31


@settings(max_examples=40, deadline=None)
@given(
    days=st.integers(1, 40),
    max_skill=st.integers(1, 12),
    practise_frac=st.floats(0.05, 1.0),
    watch_ratio=st.floats(0.05, 0.9),
    p_forget=st.floats(0.0, 0.3),
    skill_frac=st.floats(0.0, 1.0),
    curve=st.sampled_from(["linear", "convex", "concave"]),
)
def test_drummer_relations_across_parameters(days, max_skill, practise_frac, watch_ratio, p_forget, skill_frac, curve):
    # The regime in which the month is too short to surely master the drums (see the docstring):
    # days * p_practise <= max_skill, and 0 < p_watch < p_practise < 1. (With fast forgetting,
    # e.g. p_forget = 0.5 over 40 days, chilling's advantages shrink to ~1e-10: still positive,
    # but then too close to round-off for a meaningful assertion.)
    p_practise = practise_frac * min(0.95, max_skill / days)
    p_watch = watch_ratio * p_practise
    initial_skill = int(skill_frac * (max_skill - 1))
    x = np.arange(max_skill + 1) / max_skill
    pass_p = {"linear": x, "convex": x**2, "concave": np.sqrt(x)}[curve]
    mdp = drummer(
        days=days,
        max_skill=max_skill,
        p_watch=p_watch,
        p_practise=p_practise,
        p_forget=p_forget,
        pass_probability=pass_p,
        initial_skill=initial_skill,
    )
    check_drummer_relations(mdp, drummer_state(0, initial_skill, max_skill=max_skill))


def test_drummer_rejects_bad_parameters():
    with pytest.raises(ValueError, match=r"p_practise=1.5 must be a probability"):
        drummer(p_practise=1.5)
    with pytest.raises(ValueError, match="pass_probability has 3 entries; expected max_skill \\+ 1 = 11"):
        drummer(pass_probability=[0, 0.5, 1])
    with pytest.raises(ValueError, match="non-decreasing"):
        drummer(max_skill=2, pass_probability=[0, 1, 0.5])


def test_grid_world_structure_and_rendering():
    g = grid_world(size=(3, 4), walls=[(1, 1)], goals=[(0, 3)], holes=[(1, 3)], slip=0.2, gamma=0.9)
    assert g.n_states == 11 and g.n_actions == 4
    assert int(g.terminal.sum()) == 2
    sol = policy_iteration(g)
    rows = render_grid(g, sol.policy)
    assert rows[0].split()[-1] == "G" and rows[1].split()[-1] == "H" and rows[1].split()[1] == "█"
    assert rows[0].split()[:3] == ["→", "→", "→"]  # head straight for the goal along the top row
    values = render_grid(g, values=sol.values)
    assert values[0].split()[-1] == "0.00"  # terminal goal has value 0 (reward paid on entry)


def test_grid_world_dynamics():
    # Slip sends the agent sideways with slip / 2 each way; walls and edges keep it in place.
    g = grid_world(layout=["S..", "...", "..G"], slip=0.2, gamma=0.9)
    P = g.transition_tensor()
    right, up = 1, 0
    assert P[0, right, 1] == pytest.approx(0.8)  # intended
    assert P[0, right, 3] == pytest.approx(0.1)  # slipped down
    assert P[0, right, 0] == pytest.approx(0.1)  # slipped up into the edge: stay
    assert P[0, up, 0] == pytest.approx(0.9)  # up or left: edge
    assert g.R[7, right] == pytest.approx(0.8)  # (2,1) -> goal with prob 0.8, reward 1
    with pytest.raises(ValueError, match="slip=1.5"):
        grid_world(slip=1.5)
    with pytest.raises(ValueError, match="unknown cell characters"):
        grid_world(layout=["S.X"])
