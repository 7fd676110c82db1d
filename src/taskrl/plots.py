"""Pictures of runs from their ``metrics.csv``.

- `plot_learning_curve`: one run's ``learning_curve.png``: success and return against env steps
  and wall-clock, the agent's training scalars (losses, Q, temperature), and per-task success for
  multi-task runs;
- `compare_runs`: ``taskrl plot``: several runs or folders of seeds, success (and return)
  with the mean and a 95% band over seeds, per-task panels, and a summary table (final and best
  success, env steps and time to a threshold).

Tick labels read ``20k`` / ``1.2M`` at any scale.
"""

from __future__ import annotations

import csv
import math
import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from taskrl.logger import read_metrics

__all__ = ["compare_runs", "find_runs", "human_number", "plot_learning_curve"]

#: Scalars of the agent's updates worth a panel, when a run logs them.
TRAINING_SCALARS = ("loss", "critic_loss", "actor_loss", "policy_loss", "value_loss", "q_mean", "alpha", "entropy")


def human_number(x: float, _pos: Any = None) -> str:
    """``1500 -> 1.5k``, ``2_000_000 -> 2M``: tick labels that never run into each other."""
    for size, suffix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(x) >= size:
            text = f"{x / size:.1f}".rstrip("0").rstrip(".")
            return f"{text}{suffix}"
    return f"{x:g}"


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    return plt, FuncFormatter(human_number), MaxNLocator


def _style(ax, formatter, locator, xlabel: str, ylabel: str) -> None:
    ax.xaxis.set_major_formatter(formatter)
    ax.xaxis.set_major_locator(locator(nbins=5))
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)


def x_axis(rows: list[dict[str, Any]]) -> tuple[str, str]:
    """``(column, label)`` of a run's progress: env steps, or gradient updates for an offline run
    (one that never steps an env while it trains)."""
    if rows and not any(r.get("env_steps") for r in rows) and any(r.get("updates") for r in rows):
        return "updates", "gradient updates"
    return "env_steps", "environment steps"


def _column(rows: list[dict[str, Any]], name: str) -> tuple[list[float], list[float]]:
    """(progress, values) of the rows where ``name`` has a value."""
    x = x_axis(rows)[0]
    pairs = [(r[x], r[name]) for r in rows if r.get(name) is not None]
    return [p[0] for p in pairs], [p[1] for p in pairs]


def plot_learning_curve(metrics_csv: Path, out_png: Path, title: str = "") -> Path:
    """Success and return against env steps and wall-clock, the training scalars the agent logged,
    and one line per task for multi-task runs."""
    plt, formatter, locator = _pyplot()
    rows = read_metrics(metrics_csv)
    columns = list(rows[0]) if rows else []
    scalars = [c for c in TRAINING_SCALARS if c in columns]
    tasks = [c for c in columns if c.startswith("success/")]
    xlabel = x_axis(rows)[1]
    panels = 3 + len(scalars) + (1 if tasks else 0)
    cols = min(panels, 3)
    rows_n = math.ceil(panels / cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(4.2 * cols, 3.2 * rows_n), squeeze=False)
    axes = list(axes.flat)
    steps, success = _column(rows, "success_rate")
    seconds = [r["wall_seconds"] for r in rows if r.get("success_rate") is not None]
    axes[0].plot(steps, success, marker="o", markersize=3)
    _style(axes[0], formatter, locator, xlabel, "evaluation success rate")
    axes[1].plot(seconds, success, marker="o", markersize=3)
    _style(axes[1], formatter, locator, "training seconds", "evaluation success rate")
    for ax in axes[:2]:
        ax.set_ylim(-0.02, 1.02)
    axes[2].plot(*_column(rows, "eval_return"), marker="o", markersize=3, color="tab:orange")
    _style(axes[2], formatter, locator, xlabel, "evaluation return")
    for ax, name in zip(axes[3:], scalars):
        ax.plot(*_column(rows, name), color="tab:gray")
        _style(ax, formatter, locator, xlabel, name)
        if name == "alpha":
            ax.set_yscale("log")
    if tasks:
        ax = axes[3 + len(scalars)]
        for name in tasks:
            ax.plot(*_column(rows, name), label=name.split("/", 1)[1], linewidth=1)
        _style(ax, formatter, locator, xlabel, "success per task")
        ax.set_ylim(-0.02, 1.02)
        ax.legend(fontsize=6, ncol=2 if len(tasks) > 6 else 1)
    for ax in axes[panels:]:
        ax.axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return Path(out_png)


# ---------------------------------------------------------------------- several runs
#: the columns every run's ``metrics.csv`` has (a file without them was not written by a run)
RUN_COLUMNS = ("env_steps", "updates", "success_rate")
#: the image formats ``taskrl plot --out`` writes (matplotlib picks the format by the suffix)
PLOT_FORMATS = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


def is_run_metrics(path: Path) -> bool:
    """Whether ``path`` is a run's ``metrics.csv``: its header names `RUN_COLUMNS`."""
    try:
        with Path(path).open() as f:
            header = next(csv.reader(f), [])
    except (OSError, UnicodeDecodeError, csv.Error):
        return False
    return set(RUN_COLUMNS) <= set(header)


def find_runs(path: str | Path) -> list[Path]:
    """A run directory itself, or the run directories below a folder (e.g. ``seed_0``, ``seed_1``); a folder
    whose ``metrics.csv`` was not written by a run (`is_run_metrics`) is none."""
    path = Path(path)
    if is_run_metrics(path / "metrics.csv"):
        return [path]
    return sorted(p.parent for p in path.glob("*/metrics.csv") if is_run_metrics(p))


def _band(values: Sequence[float]) -> tuple[float, float]:
    """Mean and the half-width of its 95% interval (Student's t over the seeds)."""
    n = len(values)
    mean = sum(values) / n
    if n < 2:
        return mean, 0.0
    from scipy import stats

    sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (n - 1))
    return mean, float(stats.t.ppf(0.975, n - 1)) * sd / math.sqrt(n)


def _on_grid(rows: list[dict[str, Any]], name: str, grid: list[float], x: str = "env_steps") -> list[float]:
    import numpy as np

    xs, ys = zip(*[(r[x], r[name]) for r in rows if r.get(name) is not None]) if rows else ((), ())
    return list(np.interp(grid, xs, ys)) if xs else [float("nan")] * len(grid)


def _reached(rows: list[dict[str, Any]], threshold: float) -> tuple[float | None, float | None]:
    x = x_axis(rows)[0]
    for r in rows:
        if r.get("success_rate") is not None and r["success_rate"] >= threshold - 1e-9:
            return r[x], r["wall_seconds"]
    return None, None


def compare_runs(groups: dict[str, list[Path]], out_png: Path, threshold: float = 0.9) -> list[dict[str, Any]]:
    """Plot every group (one line each: the mean over its runs and a 95% band) and return its summary.

    A group is a list of run directories (the seeds of one setting). Curves of a group are compared
    on the env steps of its first run (others interpolated onto them). Per-task panels are added when
    the runs are multi-task. Also writes ``out_png`` with ``.csv``: the summary table.
    """
    plt, formatter, locator = _pyplot()
    data = {name: [read_metrics(r / "metrics.csv") for r in runs] for name, runs in groups.items()}
    tasks = sorted({c for runs in data.values() for rows in runs for c in (rows[0] if rows else {}) if c.startswith("success/")})
    panels = 3 + len(tasks)
    cols = min(panels, 3)
    fig, axes = plt.subplots(math.ceil(panels / cols), cols, figsize=(4.4 * cols, 3.3 * math.ceil(panels / cols)), squeeze=False)
    axes = list(axes.flat)
    summary = []
    for name, runs in data.items():
        runs = [rows for rows in runs if rows]
        if not runs:
            continue
        x, xlabel = x_axis(runs[0])
        grid = [r[x] for r in runs[0] if r.get("success_rate") is not None]
        means: dict[str, list[float]] = {}
        for ax, column in ((axes[0], "success_rate"), (axes[2], "eval_return"), *zip(axes[3:], tasks)):
            curves = [_on_grid(rows, column, grid, x) for rows in runs]
            bands = [_band([c[i] for c in curves]) for i in range(len(grid))]
            means[column] = [b[0] for b in bands]
            line = ax.plot(grid, means[column], label=f"{name} ({len(runs)})")[0]
            low, high = [m - h for m, h in bands], [m + h for m, h in bands]
            if column.startswith("success"):  # a rate: the band stays within what a rate can be
                low, high = [max(v, 0.0) for v in low], [min(v, 1.0) for v in high]
            ax.fill_between(grid, low, high, color=line.get_color(), alpha=0.2)
        seconds = [_on_grid(rows, "wall_seconds", grid, x) for rows in runs]  # mean training seconds at each grid step
        axes[1].plot([statistics.fmean(s[i] for s in seconds) for i in range(len(grid))], means["success_rate"], label=name)
        finals = [next(r["success_rate"] for r in reversed(rows) if r.get("success_rate") is not None) for rows in runs]
        bests = [max(r["success_rate"] for r in rows if r.get("success_rate") is not None) for rows in runs]
        reached = [_reached(rows, threshold) for rows in runs]
        hit = [r for r in reached if r[0] is not None]
        final_mean, final_half = _band(finals)
        summary.append(
            {
                "runs": name,
                "seeds": len(runs),
                "final_success": final_mean,
                "final_success_ci95": final_half,
                "best_success": statistics.fmean(bests),
                f"reached_{threshold:g}": f"{len(hit)}/{len(runs)}",
                "median_env_steps_to_threshold": _median([h[0] for h in hit]),
                "median_seconds_to_threshold": _median([h[1] for h in hit]),
            }
        )
    progress = x_axis(next((rows for runs in data.values() for rows in runs if rows), []))[1]
    labels = (
        (axes[0], progress, "success rate (mean, 95% band)"),
        (axes[1], "training seconds", "success rate (mean)"),
        (axes[2], progress, "evaluation return"),
        *((ax, progress, t) for ax, t in zip(axes[3:], tasks)),
    )
    for ax, label, ylabel in labels:
        _style(ax, formatter, locator, label, ylabel)
    for ax in axes[:2] + axes[3 : 3 + len(tasks)]:
        ax.set_ylim(-0.02, 1.02)
    axes[0].legend(fontsize=7)
    for ax in axes[panels:]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    csv_path = Path(out_png).with_suffix(".csv")
    if summary:
        with csv_path.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(summary[0]))
            writer.writeheader()
            writer.writerows(summary)
    return summary


def _median(values: Sequence[float]) -> float | None:
    return statistics.median(values) if values else None
