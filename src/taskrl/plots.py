"""Learning-curve PNGs from a run's ``metrics.csv``."""

from __future__ import annotations

from pathlib import Path

from taskrl.logger import read_metrics


def plot_learning_curve(metrics_csv: Path, out_png: Path, title: str = "") -> Path:
    """Success rate against environment steps and against wall-clock seconds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_metrics(metrics_csv)
    steps = [r["env_steps"] for r in rows]
    seconds = [r["wall_seconds"] for r in rows]
    success = [r["success_rate"] for r in rows]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 3.8), sharey=True)
    for ax, x, label in ((left, steps, "environment steps"), (right, seconds, "wall-clock seconds")):
        ax.plot(x, success, marker="o", markersize=3)
        ax.set_xlabel(label)
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
    left.set_ylabel("evaluation success rate")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out_png, dpi=110)
    plt.close(fig)
    return Path(out_png)
