"""`taskrl solve ...` (taskrl.tabular.cli.main)."""

import re

import pytest

from taskrl.tabular import drummer, policy_iteration
from taskrl.tabular.cli import ENVS, METHODS, main


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_solve_drummer_prints_tables_and_the_optimal_value(capsys):
    code, out, err = run(capsys, "drummer", "--max-rows", "5")
    assert code == 0, err
    assert "policy-iteration: 2 improvement rounds" in out and "converged=True" in out
    assert re.search(r"time \d+\.\d+ ms", out)
    for header in ("Q(chill)", "Q(watch)", "Q(practise)", "A(practise)", "day 0, skill 0 [start]"):
        assert header in out
    v0 = float(re.search(r"V\*\(start\) = ([\d.]+)", out).group(1))
    assert v0 == pytest.approx(policy_iteration(drummer()).values[0], abs=1e-6)
    assert "327 more states not shown" in out


@pytest.mark.parametrize("method, marker", [("policy-iteration", "improvement rounds"), ("value-iteration", "sweeps")])
def test_solve_frozenlake_renders_the_policy_grid(capsys, method, marker):
    code, out, err = run(capsys, "FrozenLake-v1", "--method", method)
    assert code == 0, err
    assert marker in out
    grid = out.split("policy:\n")[1].split("\n\n")[0].splitlines()
    assert len(grid) == 4 and grid[1].split()[1] == "H" and grid[3].split()[3] == "G"
    assert set(grid[0].split()) <= set("←↓→↑")
    assert "V*(start) = 0.542026" in out  # known optimum of the 4x4 slippery lake, gamma 0.99


def test_solve_q_learning_reports_error_to_q_star(capsys):
    code, out, err = run(capsys, "gridworld", "--method", "q-learning", "--episodes", "300", "--seed", "1")
    assert code == 0, err
    assert "q-learning: 300 episodes" in out
    assert re.search(r"max \|Q - Q\*\| over visited pairs = [\d.e-]+", out)
    assert "█" in out  # walls drawn in the grid


def test_solve_fitted_q_on_taxi(capsys):
    code, out, err = run(capsys, "Taxi-v4", "--method", "fitted-q", "--samples", "20000", "--max-rows", "2")
    assert code == 0, err
    assert "fitted-q: 20000 transitions" in out and "passenger" in out


@pytest.mark.parametrize(
    "argv, field",
    [
        (["Pong-v5"], "env 'Pong-v5' is not one of: " + ", ".join(ENVS)),
        (["drummer", "--method", "sarsa"], "method 'sarsa' is not one of: " + ", ".join(METHODS)),
        (["FrozenLake-v1", "--gamma", "1.5"], "gamma=1.5 is outside [0, 1)"),
        (["drummer", "--episodes", "0"], "episodes=0 must be >= 1"),
        (["drummer", "--gamma", "abc"], "argument --gamma: invalid float value"),
        (["drummer", "--bogus"], "unrecognized arguments: --bogus"),
        ([], "the following arguments are required: env"),
    ],
)
def test_bad_input_gives_one_line_error_and_exit_code_2(capsys, argv, field):
    code, out, err = run(capsys, *argv)
    assert code == 2
    assert out == ""
    assert err.count("\n") == 1 and err.startswith("taskrl solve: error: ")
    assert field in err


def test_help_exits_zero(capsys):
    code, out, _ = run(capsys, "--help")
    assert code == 0 and "policy-iteration" in out
