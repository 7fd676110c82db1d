"""What a person sees while a run trains: a progress bar with live success, then a final table."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table


def _clock(seconds: float) -> str:
    seconds = max(int(seconds), 0)
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


class ConsoleReporter:
    """What a run prints while it trains.

    With a terminal, a rich progress bar (success, return, steps/s). Without one (nohup, SLURM, CI,
    a pipe), one plain line per evaluation, flushed at once::

        bitflip-her  step 12,000/60,000 (20%)  success 0.93  return -2.10  8,123 steps/s  95 updates/s  elapsed 0:00:12  ETA 0:00:48

    Args:
        title: the run's name (its preset) at the start of every line.
        total_steps: env steps the run trains for.
        start_step: where a resumed run starts.
        enabled: print anything at all.
        log_every: also print a heartbeat line every this many seconds between evaluations (0: never).
        terminal: force the bar (True) or the plain lines (False); default: whether stderr is a terminal.
        file: where the plain lines go (default stderr).
        axis: the row's progress column: ``env_steps``, or ``updates`` for offline runs.
    """

    def __init__(
        self,
        title: str,
        total_steps: int,
        start_step: int = 0,
        enabled: bool = True,
        log_every: float = 0.0,
        terminal: bool | None = None,
        file: Any = None,
        axis: str = "env_steps",
    ) -> None:
        self.title, self.total_steps, self.enabled, self.log_every = title, total_steps, enabled, log_every
        self.axis = axis  # what the bar counts: env_steps, or updates for offline runs
        self.console = Console(stderr=True)
        self.terminal = self.console.is_terminal if terminal is None else terminal
        self.file = file if file is not None else sys.stderr
        self.started, self.start_step = time.monotonic(), start_step
        self.last_line = self.started
        self.last: dict[str, Any] = {}
        self.progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("steps  success [bold green]{task.fields[success]}  return {task.fields[ret]}"),
            TextColumn("{task.fields[speed]}"),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=self.console,
            disable=not (enabled and self.terminal),
        )
        self.task = self.progress.add_task(title, total=total_steps, completed=start_step, success="-", ret="-", speed="")

    def __enter__(self) -> ConsoleReporter:
        self.progress.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.progress.stop()

    def update(self, row: dict[str, Any]) -> None:
        """A metrics row (an evaluation): the bar moves, or one line is printed."""
        self.last = row
        if self.terminal:
            self.progress.update(
                self.task,
                completed=row[self.axis],
                success=f"{row['success_rate']:.2f}",
                ret=f"{row.get('eval_return', float('nan')):.2f}",
                speed=f"{row[self.axis + '_per_s']:,.0f} {'steps' if self.axis == 'env_steps' else 'updates'}/s",
            )
        elif self.enabled:
            self._line(row[self.axis], row)

    def heartbeat(self, env_steps: int) -> None:
        """Called as training goes: a plain line every ``log_every`` seconds between evaluations."""
        if self.enabled and not self.terminal and self.log_every > 0 and time.monotonic() - self.last_line >= self.log_every:
            self._line(env_steps, self.last, beat=True)

    def _line(self, env_steps: int, row: dict[str, Any], beat: bool = False) -> None:
        now = time.monotonic()
        elapsed = now - self.started
        done = max(env_steps - self.start_step, 0)
        eta = elapsed / done * max(self.total_steps - env_steps, 0) if done else float("nan")
        unit = "step" if self.axis == "env_steps" else "update"
        parts = [self.title, f"{unit} {env_steps:,}/{self.total_steps:,} ({100 * env_steps / max(self.total_steps, 1):.0f}%)"]
        if row:
            what = "last success" if beat else "success"
            parts += [
                f"{what} {row['success_rate']:.2f}",
                f"return {row.get('eval_return', float('nan')):.2f}",
                f"{row.get('env_steps_per_s', 0):,.0f} steps/s",
                f"{row.get('updates_per_s', 0):,.0f} updates/s",
            ]
        parts += [f"elapsed {_clock(elapsed)}", f"ETA {_clock(eta) if eta == eta else '-'}"]
        print("  ".join(parts), file=self.file, flush=True)
        self.last_line = now


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
    """A ``rich`` table of [`evaluate_per_task`][taskrl.training.per_task.evaluate_per_task]'s result, with the mean over tasks last."""
    table = Table(title=title)
    table.add_column("#", justify="right")
    table.add_column("task")
    table.add_column("success", justify="right")
    table.add_column("episodes", justify="right")
    table.add_column("return", justify="right")
    intervals = any("success_ci95" in row for row in result["tasks"].values())
    if intervals:
        table.add_column("95% interval", justify="right")
    for name, row in result["tasks"].items():
        cells = [str(row["index"]), name, f"{row['success_rate']:.2f}", str(row["episodes"]), f"{row['mean_return']:.1f}"]
        if intervals:
            lo, hi = row["success_ci95"]
            cells.append(f"{lo:.2f} - {hi:.2f}")
        table.add_row(*cells)
    table.add_section()
    table.add_row("", "[bold]mean over tasks", f"[bold]{result['mean_success_rate']:.3f}", "", "", *([""] if intervals else []))
    return table


def eval_table(result: dict[str, Any], run_dir: Any) -> Table:
    """``taskrl eval``'s summary: success and return with their 95% intervals, and what was evaluated."""
    table = Table(title=f"evaluation of {run_dir}", show_header=False)
    table.add_column(style="bold")
    table.add_column()
    lo, hi = result["success_ci95"]
    table.add_row("success rate", f"{result['success_rate']:.3f}  (95% interval {lo:.3f} - {hi:.3f})")
    ret = f"{result['eval_return']:.2f}"
    if "eval_return_ci95" in result:
        rlo, rhi = result["eval_return_ci95"]
        ret += f"  (95% interval {rlo:.2f} - {rhi:.2f})"
    table.add_row("return", ret)
    table.add_row("episode length", f"{result['eval_length']:.1f}")
    table.add_row("episodes", f"{result['episodes']:,}" + (" per task" if "tasks" in result else ""))
    table.add_row("checkpoint", f"{result['checkpoint_step']:,} {result.get('checkpoint_unit', 'env steps')}")
    return table


def summary_table(summary: list[dict[str, Any]], title: str = "runs compared") -> Table:
    """``taskrl plot``'s table: per group of seeds, final success (mean and 95% half-width), best, and
    the env steps and seconds to the threshold (medians over the seeds that reached it)."""
    table = Table(title=title)
    for column in ("runs", "seeds", "final success", "best success", "reached", "env steps to it", "seconds to it"):
        table.add_column(column, justify="left" if column == "runs" else "right")
    for row in summary:
        reached = next(k for k in row if k.startswith("reached_"))

        def num(value: Any, fmt: str) -> str:
            return "-" if value is None else format(value, fmt)

        table.add_row(
            str(row["runs"]),
            str(row["seeds"]),
            f"{row['final_success']:.2f} +- {row['final_success_ci95']:.2f}",
            f"{row['best_success']:.2f}",
            f"{row[reached]} (>= {reached.split('_', 1)[1]})",
            num(row["median_env_steps_to_threshold"], ",.0f"),
            num(row["median_seconds_to_threshold"], ".1f"),
        )
    return table


class CollectionProgress:
    """A progress bar of kept demonstrations (``update(kept, wanted)``); plain lines every 10 s without a terminal."""

    def __init__(self, title: str, enabled: bool = True) -> None:
        self.title, self.enabled = title, enabled
        self.console = Console(stderr=True)
        self.progress = Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("episodes"),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
            console=self.console,
        )
        self.task = None
        self.last_line = 0.0

    def __enter__(self) -> CollectionProgress:
        if self.enabled and self.console.is_terminal:
            self.progress.start()
        return self

    def update(self, kept: int, wanted: int) -> None:
        if not self.enabled:
            return
        if self.console.is_terminal:
            if self.task is None:
                self.task = self.progress.add_task(self.title, total=wanted)
            self.progress.update(self.task, completed=kept)
        elif time.monotonic() - self.last_line >= 10.0 or kept == wanted:
            self.last_line = time.monotonic()
            print(f"{self.title}  {kept:,}/{wanted:,} episodes", file=sys.stderr, flush=True)

    def __exit__(self, *exc: Any) -> None:
        if self.progress.live.is_started:
            self.progress.stop()


def dataset_table(metadata: dict[str, Any], path: Any) -> Table:
    """A demonstration dataset's card: episodes, expert success and mean length per task, and totals."""
    card = metadata.get("card") or {}
    table = Table(title=f"dataset {path} ({card.get('source', 'unknown source')})")
    table.add_column("task")
    table.add_column("episodes", justify="right")
    table.add_column("expert success", justify="right")
    table.add_column("mean length", justify="right")
    splits = card.get("splits") or {}
    if splits:
        table.add_column("split")
    episodes, success, length = (
        card.get("episodes_per_task", {}),
        card.get("expert_success_rate", {}),
        card.get("mean_length", {}),
    )
    for task in metadata.get("tasks", []):
        name = task.get("name", "?")
        cells = [name, str(episodes.get(name, "?")), _fraction(success.get(name)), _fraction(length.get(name), ".1f")]
        if splits:
            cells.append(next((s for s, names in splits.items() if name in names), ""))
        table.add_row(*cells)
    table.add_section()
    size = metadata.get("dataset_size")
    table.add_row(
        "[bold]total",
        f"[bold]{metadata.get('total_episodes', 0):,}",
        "",
        f"{metadata.get('total_steps', 0):,} steps",
        *([""] if splits else []),
    )
    notes = [f"noise std {card.get('noise_std', 0)}", f"seed {card.get('seed', '?')}"]
    if size is not None:
        notes.append(f"{size} MB")
    if "collection_seconds" in card:
        notes.append(f"collected in {card['collection_seconds']:.0f} s")
    table.caption = ", ".join(notes)
    return table


def _fraction(value: Any, spec: str = ".2f") -> str:
    return format(value, spec) if isinstance(value, (int, float)) else "?"
