"""``taskrl solve ENV``: solve a finite MDP and print V, Q and A tables, the policy and timings.

The top-level ``taskrl`` command passes the arguments after ``solve`` to `main`.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

import numpy as np

from taskrl.tabular.dp import Solution, evaluate_policy, policy_iteration, value_iteration
from taskrl.tabular.examples import drummer, grid_world
from taskrl.tabular.learning import fitted_q_iteration, q_learning, sample_transitions
from taskrl.tabular.mdp import FiniteMDP
from taskrl.tabular.render import render_grid
from taskrl.tabular.toytext import TOY_TEXT_ENVS, mdp_from_gymnasium

__all__ = ["main", "ENVS", "METHODS"]

ENVS = ("drummer", "gridworld") + TOY_TEXT_ENVS
METHODS = ("policy-iteration", "value-iteration", "q-learning", "fitted-q")
DEFAULT_GAMMA = {"drummer": 1.0, "gridworld": 0.95}


class _UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line instead of usage + message
        raise _UsageError(message)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(
        prog="taskrl solve",
        description="Solve a finite MDP exactly (or learn it) and print V, Q, A and the policy.",
    )
    p.add_argument("env", help=f"environment: {', '.join(ENVS)}")
    p.add_argument("--method", default="policy-iteration", help=f"one of: {', '.join(METHODS)} (default: policy-iteration)")
    p.add_argument("--gamma", type=float, default=None, help="discount (default: 1 for drummer, 0.95 gridworld, 0.99 otherwise)")
    p.add_argument("--tol", type=float, default=1e-10, help="value-iteration / fitted-Q stopping tolerance (default: 1e-10)")
    p.add_argument("--episodes", type=int, default=20_000, help="q-learning episodes (default: 20000)")
    p.add_argument("--epsilon", type=float, default=0.1, help="q-learning exploration rate (default: 0.1)")
    p.add_argument("--samples", type=int, default=None, help="fitted-q dataset size (default: 100 per state-action pair)")
    p.add_argument("--seed", type=int, default=0, help="random seed for q-learning / fitted-q (default: 0)")
    p.add_argument("--max-rows", type=int, default=24, help="at most this many states in the tables (default: 24)")
    return p


def _make_env(name: str, gamma: float | None) -> tuple[FiniteMDP, int]:
    """The MDP for ``name`` and its episode length limit."""
    g = DEFAULT_GAMMA.get(name, 0.99) if gamma is None else gamma
    if name == "drummer":
        return drummer(gamma=g), 1_000
    if name == "gridworld":
        return grid_world(gamma=g), 200
    import gymnasium as gym

    env = gym.make(name)
    limit = env.spec.max_episode_steps if env.spec is not None and env.spec.max_episode_steps else 1_000
    return mdp_from_gymnasium(env, gamma=g), limit


def _fmt(x: float) -> str:
    return f"{x:.4g}" if abs(x) >= 1e-4 or x == 0 else f"{x:.2e}"


def _print_tables(console, mdp: FiniteMDP, V: np.ndarray, Q: np.ndarray, policy: np.ndarray, max_rows: int) -> None:
    from rich.markup import escape
    from rich.table import Table

    S, A = mdp.n_states, mdp.n_actions
    Adv = Q - V[:, None]
    # Start states first, then the rest in index order.
    order = np.concatenate([np.flatnonzero(mdp.initial > 0), np.flatnonzero(mdp.initial == 0)])[:max_rows]
    table = Table(title=f"V, Q and A = Q - V ({len(order)} of {S} states)", show_lines=False)
    table.add_column("state")
    table.add_column("V", justify="right")
    for a in mdp.action_names:
        table.add_column(escape(f"Q({a})"), justify="right")
    for a in mdp.action_names:
        table.add_column(escape(f"A({a})"), justify="right")
    table.add_column("policy")
    for s in order:
        label = mdp.state_names[s] + (" [start]" if mdp.initial[s] > 0 else "") + (" [terminal]" if mdp.terminal[s] else "")
        table.add_row(
            escape(label),
            _fmt(V[s]),
            *(_fmt(Q[s, a]) for a in range(A)),
            *(_fmt(Adv[s, a]) for a in range(A)),
            "-" if mdp.terminal[s] else escape(mdp.action_names[int(policy[s])]),
        )
    console.print(table)
    if len(order) < S:
        console.print(f"({S - len(order)} more states not shown; use --max-rows)")
    if mdp.grid is not None:
        console.print("\npolicy:")
        console.print("\n".join(render_grid(mdp, policy)), markup=False)
        console.print("\nvalues:")
        console.print("\n".join(render_grid(mdp, values=V)), markup=False)


def _run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.markup import escape

    mdp, max_steps = _make_env(args.env, args.gamma)
    console = Console(highlight=False)
    # Tables need about 11 columns per number; don't squeeze them into 80 when piped.
    name_width = max(len(n) for n in mdp.state_names) + len(" [terminal]")
    needed = name_width + 4 + 13 * (2 * mdp.n_actions + 2)
    if not console.is_terminal:
        console = Console(highlight=False, width=max(needed, 80))
    console.print(
        f"[bold]{escape(mdp.name)}[/bold]: {mdp.n_states} states x {mdp.n_actions} actions, gamma={mdp.gamma:g}, "
        f"{int(mdp.terminal.sum())} terminal states, {mdp.P_by_action.nnz} transitions"
    )
    start = mdp.initial
    if args.method in ("policy-iteration", "value-iteration"):
        if args.method == "policy-iteration":
            sol: Solution = policy_iteration(mdp)
            what = "improvement rounds (exact evaluation)"
        else:
            sol = value_iteration(mdp, tol=args.tol)
            what = f"sweeps (tol {args.tol:g})"
        console.print(f"{args.method}: {sol.iterations} {what}, converged={sol.converged}, time {sol.seconds * 1e3:.2f} ms")
        _print_tables(console, mdp, sol.values, sol.q_values, sol.policy, args.max_rows)
        console.print(f"\nV*(start) = {float(start @ sol.values):.6g}")
        return 0

    # Learning methods: compare with the exact solution so the user can check the theory.
    exact = value_iteration(mdp, tol=1e-12)
    t0 = time.perf_counter()
    if args.method == "q-learning":
        res = q_learning(mdp, episodes=args.episodes, epsilon=args.epsilon, max_steps=max_steps, seed=args.seed)
        Q, visited = res.q_values, res.visits > 0
        detail = f"{res.episodes} episodes, {res.steps} steps"
    else:
        live = int((~mdp.terminal).sum())
        n = args.samples if args.samples is not None else 100 * live * mdp.n_actions
        data = sample_transitions(mdp, n, seed=args.seed)
        fq = fitted_q_iteration(data, n_states=mdp.n_states, n_actions=mdp.n_actions, gamma=mdp.gamma, tol=args.tol)
        Q, visited = fq.q_values, fq.counts > 0
        detail = f"{n} transitions, {fq.iterations} iterations, converged={fq.converged}"
    seconds = time.perf_counter() - t0
    policy = Q.argmax(axis=1)
    V = Q.max(axis=1)
    live = visited & ~mdp.terminal[:, None]
    err = float(np.abs(Q - exact.q_values)[live].max(initial=0.0))
    console.print(f"{args.method}: {detail}, time {seconds * 1e3:.1f} ms")
    _print_tables(console, mdp, V, Q, policy, args.max_rows)
    v_greedy = evaluate_policy(mdp, policy)
    console.print(
        f"\nmax |Q - Q*| over visited pairs = {err:.4g}; "
        f"greedy policy V(start) = {float(start @ v_greedy):.6g} vs V*(start) = {float(start @ exact.values):.6g}"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point for ``taskrl solve ARGS``; returns the process exit code.

    Args:
        argv: the arguments after ``solve`` (default: ``sys.argv[1:]``).
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = _parser().parse_args(argv)
    except _UsageError as e:
        print(f"taskrl solve: error: {e}", file=sys.stderr)
        return 2
    except SystemExit as e:  # --help
        return int(e.code or 0)
    problems = []
    if args.env not in ENVS:
        problems.append(f"env {args.env!r} is not one of: {', '.join(ENVS)}")
    if args.method not in METHODS:
        problems.append(f"method {args.method!r} is not one of: {', '.join(METHODS)}")
    if args.episodes < 1:
        problems.append(f"episodes={args.episodes} must be >= 1")
    if not args.tol > 0:
        problems.append(f"tol={args.tol} must be > 0")
    if not 0 <= args.epsilon <= 1:
        problems.append(f"epsilon={args.epsilon} must be in [0, 1]")
    if args.samples is not None and args.samples < 1:
        problems.append(f"samples={args.samples} must be >= 1")
    if args.max_rows < 1:
        problems.append(f"max-rows={args.max_rows} must be >= 1")
    if problems:
        print(f"taskrl solve: error: {problems[0]}", file=sys.stderr)
        return 2
    try:
        return _run(args)
    except ValueError as e:  # e.g. gamma out of range: the MDP constructor names the field
        print(f"taskrl solve: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
