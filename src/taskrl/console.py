"""What a person sees while a run trains: a progress bar with live success, then a final table."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table


class ConsoleReporter:
    """Progress bar over environment steps; ``enabled=False`` keeps the console quiet."""

    def __init__(self, title: str, total_steps: int, start_step: int = 0, enabled: bool = True) -> None:
        self.enabled = enabled
        self.console = Console(stderr=True)
        self.progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("steps  success [bold green]{task.fields[success]}"),
            TextColumn("{task.fields[speed]}"),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=self.console,
            disable=not enabled,
        )
        self.task = self.progress.add_task(title, total=total_steps, completed=start_step, success="-", speed="")

    def __enter__(self) -> ConsoleReporter:
        self.progress.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.progress.stop()

    def update(self, row: dict[str, Any]) -> None:
        self.progress.update(
            self.task,
            completed=row["env_steps"],
            success=f"{row['success_rate']:.2f}",
            speed=f"{row['env_steps_per_s']:,.0f} steps/s",
        )


def final_table(row: dict[str, Any], run_dir: Path, curve: Path | None) -> Table:
    table = Table(title="taskrl run summary", show_header=False)
    table.add_column(style="bold")
    table.add_column()
    table.add_row("success rate (eval)", f"{row['success_rate']:.3f}")
    table.add_row("eval return", f"{row['eval_return']:.2f}")
    table.add_row("env steps", f"{int(row['env_steps']):,}")
    table.add_row("gradient updates", f"{int(row['updates']):,}")
    table.add_row("training wall-clock", f"{row['wall_seconds']:.1f} s")
    table.add_row("run directory", str(run_dir))
    if curve is not None:
        table.add_row("learning curve", str(curve))
    return table


def per_task_table(result: dict[str, Any], title: str = "per-task success"):
    """A ``rich`` table of :func:`~taskrl.training.per_task.evaluate_per_task`'s result, with the mean over tasks last."""
    table = Table(title=title)
    table.add_column("#", justify="right")
    table.add_column("task")
    table.add_column("success", justify="right")
    table.add_column("episodes", justify="right")
    table.add_column("return", justify="right")
    for name, row in result["tasks"].items():
        table.add_row(str(row["index"]), name, f"{row['success_rate']:.2f}", str(row["episodes"]), f"{row['mean_return']:.1f}")
    table.add_section()
    table.add_row("", "[bold]mean over tasks", f"[bold]{result['mean_success_rate']:.3f}", "", "")
    return table
