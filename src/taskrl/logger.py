"""Metrics of a run: ``metrics.csv`` (one row per evaluation) and TensorBoard events.

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
    """

    def __init__(
        self, run_dir: Path, tensorboard: bool = True, resume_from_step: int | None = None, axis: str = "env_steps"
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

    def log_training(self, step: int, values: dict[str, float]) -> None:
        """Training scalars between evaluations, to TensorBoard only (``train/<name>``)."""
        if self.writer is not None:
            for name, value in values.items():
                self.writer.add_scalar(f"train/{name}", value, step)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


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
