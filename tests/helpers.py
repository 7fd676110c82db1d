"""Shared test helpers: a small run in this process, the ``taskrl`` command in this process or in a
child process, and a run's ``metrics.csv``. Tests import them (``from helpers import small_run``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import taskrl
from taskrl.cli import main
from taskrl.logger import read_metrics

TESTS = Path(__file__).parent


def small_run(preset: str, out: Path, **settings: Any) -> taskrl.Run:
    """``taskrl.train(preset, out=out, **settings)`` without TensorBoard files (the budget is the caller's)."""
    return taskrl.train(preset, out=out, **{"tensorboard": False, **settings})


def run_cli(capsys, *args: str) -> tuple[int, str, str]:
    """``taskrl ARGS`` in this process: exit code, stdout, stderr."""
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def cli(
    *args: str, cwd: Path | None = None, env: dict[str, str] | None = None, timeout: float = 600
) -> subprocess.CompletedProcess:
    """``taskrl ARGS`` in a child process, with the tests folder importable (``--env-module test_custom_envs``)."""
    environ = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(TESTS), os.environ.get("PYTHONPATH")]))}
    return subprocess.run(
        [sys.executable, "-m", "taskrl.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=cwd,
        env={**environ, **(env or {})},
    )


def cli_train(*args: str, cwd: Path | None = None, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``taskrl train ARGS --no-progress`` in a child process."""
    return cli("train", *args, "--no-progress", cwd=cwd, env=env)


def metrics(run_dir: Path) -> list[dict[str, Any]]:
    """The rows of a run's ``metrics.csv``, numbers converted."""
    return read_metrics(Path(run_dir) / "metrics.csv")


def successes(run_dir: Path) -> list[float]:
    """``success_rate`` at each evaluation of a run."""
    return [float(row["success_rate"]) for row in metrics(run_dir)]
