"""Metrics of a run: ``metrics.csv`` (one row per evaluation) and TensorBoard events.

Columns of ``metrics.csv``:
    env_steps        environment steps so far (all parallel environments)
    updates          gradient updates so far
    wall_seconds     training wall-clock, summed across resumes
    success_rate     fraction of evaluation episodes that reached their goal (greedy policy)
    eval_return      mean undiscounted evaluation return
    eval_length      mean evaluation episode length
    train_success    success rate of training episodes finished since the last row
    loss             mean TD loss since the last row
    q_mean           mean Q(s, a) of the sampled batches since the last row
    epsilon          exploration rate at this point
    env_steps_per_s  collection + learning throughput since the last row
    updates_per_s    gradient updates per second since the last row
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

COLUMNS = [
    "env_steps", "updates", "wall_seconds", "success_rate", "eval_return", "eval_length",
    "train_success", "loss", "q_mean", "epsilon", "env_steps_per_s", "updates_per_s",
]


class RunLogger:
    """Appends metric rows to ``metrics.csv`` and, optionally, TensorBoard.

    Args:
        run_dir: the run directory.
        tensorboard: also write TensorBoard events under ``run_dir/tensorboard``.
        resume_from_step: when resuming, rows logged after this step (by a run killed before
            its next checkpoint) are dropped so the file has no duplicates.
    """

    def __init__(self, run_dir: Path, tensorboard: bool = True, resume_from_step: int | None = None) -> None:
        self.path = Path(run_dir) / "metrics.csv"
        if resume_from_step is not None and self.path.exists():
            rows = [r for r in read_metrics(self.path) if float(r["env_steps"]) <= resume_from_step]
            self._write_rows(rows)
        elif not self.path.exists() or resume_from_step is None:
            self._write_rows([])
        self.writer = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(Path(run_dir) / "tensorboard"))

    def _write_rows(self, rows: list[dict[str, Any]]) -> None:
        with self.path.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=COLUMNS)
            writer.writeheader()
            writer.writerows(rows)

    def log(self, row: dict[str, Any]) -> None:
        with self.path.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=COLUMNS).writerow({k: row.get(k, "") for k in COLUMNS})
        if self.writer is not None:
            step = int(row["env_steps"])
            for k in COLUMNS[1:]:
                if isinstance(row.get(k), (int, float)):
                    self.writer.add_scalar(f"taskrl/{k}", row[k], step)
            self.writer.flush()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def read_metrics(path: Path) -> list[dict[str, Any]]:
    """Rows of a ``metrics.csv`` with numeric fields converted to float."""
    with Path(path).open() as f:
        return [{k: (float(v) if v not in ("", None) else None) for k, v in row.items()} for row in csv.DictReader(f)]
