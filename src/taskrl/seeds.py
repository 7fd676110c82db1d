"""Several seeds of one setting: one run per seed into one folder, then their comparison (mean and 95% band).

``taskrl train PRESET --seeds 0 1 2`` calls `train_seeds`; so can a script.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from rich.console import Console

from taskrl.config import TrainConfig
from taskrl.console import summary_table
from taskrl.errors import reason, require
from taskrl.plan import validate
from taskrl.plots import compare_runs
from taskrl.run import Run, train
from taskrl.rundir import check_new_run_dir
from taskrl.wiring.calls import default_run_dir, env_source, resolve_config

__all__ = ["SeedRuns", "train_seeds"]


@dataclasses.dataclass
class SeedRuns:
    """What `train_seeds` made.

    Attributes:
        folder: the folder holding ``seed_<s>/`` run directories and ``seeds.png`` (with ``seeds.csv``).
        runs: seed -> its [`Run`][taskrl.run.Run], for the runs that finished (a run made in another
            process has ``agent`` None: load it with [`taskrl.load`][taskrl.load]).
        failed: seed -> the error that ended its run.
        summary: the comparison's summary (success reached, env steps to the threshold, ...).
        plot: the comparison plot, when any run finished.
    """

    folder: Path
    runs: dict[int, Run]
    failed: dict[int, str]
    summary: list[dict[str, Any]]
    plot: Path | None


def _train_apart(preset: str | None, out: Path, seed: int, base: TrainConfig | None, overrides: dict[str, Any]) -> Run:
    """One seed's run in a worker process; its agent stays there (the run directory holds it)."""
    run = train(preset, out=out, seed=seed, base=base, **overrides)
    return dataclasses.replace(run, agent=None)


def train_seeds(
    preset: str | None = "bitflip-her",
    seeds: Sequence[int] = (0, 1, 2),
    *,
    out: str | Path | None = None,
    parallel: int = 1,
    progress: bool = False,
    base: TrainConfig | None = None,
    console: Console | None = None,
    **overrides: Any,
) -> SeedRuns:
    """Train ``preset`` once per seed into ``out/seed_<s>``, then compare the runs.

    Args:
        preset: as for `taskrl.train`.
        seeds: the runs' seeds (distinct).
        out: the folder of the runs (default ``runs/<preset>-seeds-<timestamp>``); must not hold a run already.
        parallel: runs at once: 1 trains them in turn in this process; more trains each in a process of its
            own (an env given as a Python object needs 1).
        progress: a progress bar per run (in turn only) and the comparison table.
        base: as for `taskrl.train`.
        console: where tables and notes go (default stderr).
        **overrides: as for `taskrl.train` (``tensorboard``, ``wandb`` and settings), except ``seed``.

    Returns:
        a `SeedRuns`. Settings are checked before any run starts (a `ConfigError`); a run that
        fails later is recorded in ``failed`` and the others still run.
    """
    require(
        isinstance(seeds, (list, tuple, range)) and all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds),
        "seeds",
        f"a list of integers >= 0, e.g. [0, 1, 2] (got {seeds!r})",
    )
    seeds = list(seeds)
    require(len(seeds) >= 1 and len(set(seeds)) == len(seeds), "seeds", f"distinct seeds, at least one (got {seeds})")
    require("seed" not in overrides, "seeds", "give seeds or seed, not both")
    require(parallel >= 1, "parallel", f"must be >= 1 (got {parallel})")
    settings = {k: v for k, v in overrides.items() if k not in ("tensorboard", "wandb", "log_every")}
    probe = dict(settings, seed=seeds[0])
    in_python = env_source(probe) is not None
    require(
        not (in_python and parallel > 1), "parallel", "a run on an env given as a Python object trains in this process: use 1"
    )
    if not in_python:  # an object's family checks it when the run starts
        validate(resolve_config(preset, None, probe, base=base))
    folder = check_new_run_dir(out if out is not None else default_run_dir(f"{preset or 'run'}-seeds"))
    folder.mkdir(parents=True, exist_ok=True)
    runs: dict[int, Run] = {}
    failed: dict[int, str] = {}
    if parallel == 1:
        for seed in seeds:
            try:
                runs[seed] = train(
                    preset, out=folder / f"seed_{seed}", seed=seed, base=base, progress=progress, console=console, **overrides
                )
            except Exception as error:  # noqa: BLE001 - the other seeds still run; the error is reported
                failed[seed] = reason(error)
            if seed in runs and runs[seed].stopped_by:  # Ctrl-C or the time limit: the remaining seeds wait too
                break
    else:
        with ProcessPoolExecutor(parallel, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = {s: pool.submit(_train_apart, preset, folder / f"seed_{s}", s, base, overrides) for s in seeds}
            for seed, future in futures.items():
                try:
                    runs[seed] = future.result()
                except Exception as error:  # noqa: BLE001 - a worker's error of any kind: the other seeds still count
                    failed[seed] = reason(error)
    summary: list[dict[str, Any]] = []
    plot = None
    if runs:
        name = preset or "run"
        plot = folder / "seeds.png"
        summary = compare_runs({name: [run.run_dir for run in runs.values()]}, plot)
        if progress:
            (console or Console(stderr=True)).print(summary_table(summary, f"{name}: {len(runs)} seeds"))
    return SeedRuns(folder, runs, failed, summary, plot)
