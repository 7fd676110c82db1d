"""Metrics of a run: ``metrics.csv`` (one row per evaluation), TensorBoard events and, optionally,
Weights & Biases (``--wandb``: the same rows and training scalars, and the run's settings).

Columns of ``metrics.csv`` (the first ones always; then the scalars the agent's ``update``
returns, averaged over the updates since the previous row, e.g. DQN's ``loss`` and ``q_mean``):
    env_steps        environment steps so far (all parallel environments)
    updates          gradient updates so far
    wall_seconds     training wall-clock, summed across resumes
    success_rate     fraction of evaluation episodes that reached their goal (greedy policy)
    eval_return      mean undiscounted evaluation return
    eval_length      mean evaluation episode length
    train_success    success rate of training episodes finished since the last row
    env_steps_per_s  collection + learning throughput since the last row
    updates_per_s    gradient updates per second since the last row
then the agent's own: its update scalars (DQN's ``loss`` and ``q_mean``, SAC's ``critic_loss``,
``actor_loss``, ``alpha``, ``entropy``, ...) and its exploration level where it has a schedule
(DQN's ``epsilon``, QT-Opt's ``random_action_prob``); multi-task runs add ``success/<task>``.
"""

from __future__ import annotations

import csv
import io
import os
import secrets
from pathlib import Path
from typing import Any

from taskrl.rundir import atomic_write_text

COLUMNS = [
    "env_steps",
    "updates",
    "wall_seconds",
    "success_rate",
    "eval_return",
    "eval_length",
    "train_success",
    "env_steps_per_s",
    "updates_per_s",
]


class RunLogger:
    """Appends metric rows to ``metrics.csv`` and, optionally, TensorBoard.

    Args:
        run_dir: the run directory.
        tensorboard: also write TensorBoard events under ``run_dir/tensorboard``.
        axis: the column that counts the run's progress (``env_steps``; ``updates`` for offline runs).
        resume_from_step: when resuming, rows logged after this step (by a run killed before
            its next checkpoint) are dropped so the file has no duplicates.
        wandb: also log to Weights & Biases: ``{"name": ..., "config": {...}}`` of the run (see `start_wandb`).
    """

    def __init__(
        self,
        run_dir: Path,
        tensorboard: bool = True,
        resume_from_step: int | None = None,
        axis: str = "env_steps",
        wandb: dict[str, Any] | None = None,
    ) -> None:
        self.path = Path(run_dir) / "metrics.csv"
        self.axis = axis  # the progress column: env_steps, or updates for offline runs
        self.columns: list[str] | None = None
        if resume_from_step is not None and self.path.exists():
            with self.path.open(newline="") as f:
                raw = list(csv.reader(f))
            self.columns = raw[0] if raw else None
            # Rows past the checkpoint (logged by a run killed before its next checkpoint) go, and so
            # does a row the kill cut short.
            rows = []
            if self.columns and axis in self.columns:
                at = self.columns.index(axis)
                for r in raw[1:]:
                    try:
                        if len(r) == len(self.columns) and float(r[at]) <= resume_from_step:
                            rows.append(dict(zip(self.columns, r)))
                    except ValueError:
                        continue
            self._write_rows(rows)
        elif self.path.exists():
            self.path.unlink()
        self.writer = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            # purge_step: TensorBoard drops the killed segment's points after the checkpoint, so a
            # resumed run's curves never hold a stretch twice or run backwards.
            purge = resume_from_step + 1 if resume_from_step is not None else None
            self.writer = SummaryWriter(str(Path(run_dir) / "tensorboard"), purge_step=purge)
        self.wandb = start_wandb(Path(run_dir), **wandb) if wandb is not None else None
        if self.wandb is not None:  # curves against the run's own progress axis, as in TensorBoard
            self.wandb.define_metric(self.axis)
            self.wandb.define_metric("*", step_metric=self.axis)

    def _write_rows(self, rows: list[dict[str, Any]]) -> None:
        """Rewrite the whole file atomically (temp file + rename)."""
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=self.columns)
        writer.writeheader()
        writer.writerows(rows)
        atomic_write_text(self.path, buffer.getvalue())

    def log(self, row: dict[str, Any]) -> None:
        if self.columns is None:  # fixed columns first, then the agent's metrics in their order
            self.columns = COLUMNS + [k for k in row if k not in COLUMNS]
            self._write_rows([])
        elif any(k not in self.columns for k in row):  # first row with the agent's metrics: widen once
            rows = read_metrics(self.path)
            self.columns += [k for k in row if k not in self.columns]
            self._write_rows(rows)
        with self.path.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=self.columns).writerow({k: row.get(k, "") for k in self.columns})
        if self.writer is not None:
            step = int(row[self.axis])
            for k in self.columns[1:]:
                if isinstance(row.get(k), (int, float)):
                    self.writer.add_scalar(f"taskrl/{k}", row[k], step)
            self.writer.flush()
        if self.wandb is not None:
            values = {f"taskrl/{k}": row[k] for k in self.columns[1:] if isinstance(row.get(k), (int, float))}
            self.wandb.log({**values, self.axis: int(row[self.axis])})

    def log_training(self, step: int, values: dict[str, float]) -> None:
        """Training scalars between evaluations, to TensorBoard only (``train/<name>``)."""
        if self.writer is not None:
            for name, value in values.items():
                self.writer.add_scalar(f"train/{name}", value, step)
        if self.wandb is not None:
            self.wandb.log({**{f"train/{k}": v for k, v in values.items()}, self.axis: step})

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
        if self.wandb is not None:
            self.wandb.finish()


def wandb_mode() -> str:
    """``WANDB_MODE`` when set; else ``online`` with an API key (``WANDB_API_KEY`` or ``wandb login``), else
    ``offline``: a machine without an account or network still logs, to ``wandb/`` in the run directory,
    for ``wandb sync`` later."""
    if os.environ.get("WANDB_MODE"):
        return os.environ["WANDB_MODE"]
    netrc = Path.home() / ".netrc"
    logged_in = netrc.exists() and "api.wandb.ai" in netrc.read_text(errors="ignore")
    return "online" if os.environ.get("WANDB_API_KEY") or logged_in else "offline"


def require_wandb() -> Any:
    """The ``wandb`` module; a `ConfigError` naming the extra where it is not installed."""
    try:
        import wandb
    except ImportError:
        from taskrl.errors import ConfigError

        raise ConfigError("wandb", "needs the wandb package: pip install 'taskrl[wandb]'") from None
    return wandb


def start_wandb(run_dir: Path, name: str, config: dict[str, Any], project: str = "taskrl") -> Any:
    """A Weights & Biases run for ``run_dir``, resumed under the same id when the run directory is resumed
    (the id is kept in ``run_dir/wandb_id``). Needs the ``wandb`` extra."""
    wandb = require_wandb()
    id_file = run_dir / "wandb_id"
    run_id = id_file.read_text().strip() if id_file.exists() else secrets.token_hex(8)
    atomic_write_text(id_file, run_id + "\n")
    run = wandb.init(
        project=os.environ.get("WANDB_PROJECT", project),
        name=name,
        id=run_id,
        resume="allow",
        dir=str(run_dir),
        config=config,
        mode=wandb_mode(),
        settings=wandb.Settings(quiet=True, console="off"),
    )
    return run


def _number(text: str | None) -> int | float | None:
    if text in ("", None):
        return None
    try:
        return int(text)  # counters stay integers when the file is rewritten
    except ValueError:
        return float(text)


def read_metrics(path: Path) -> list[dict[str, Any]]:
    """Rows of a ``metrics.csv`` with numeric fields converted to int (counters) or float."""
    with Path(path).open() as f:
        return [{k: _number(v) for k, v in row.items()} for row in csv.DictReader(f)]
