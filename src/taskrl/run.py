"""A training run end to end: build its parts, restore them, run the loop, report.

Run directory layout::

    runs/<name>/
        config.json          the resolved configuration
        run.json             the run's name (its preset)
        metrics.csv          one row per evaluation (columns in taskrl.logger)
        tensorboard/         TensorBoard events
        checkpoints/latest   name of the newest checkpoint folder
        checkpoints/step_*/  agent / replay / loop parts (safetensors + JSON)
        learning_curve.png   success rate against env steps and wall-clock
        per_task_success.json  multi-task runs: the last evaluation, per task
        tasks.json           runs on a TaskSet given in Python: its tasks

How the run runs comes from its run mode ([`taskrl.runmodes`][taskrl.runmodes]), its parts from [`taskrl.wiring`][taskrl.wiring], and
everything env- or algorithm-specific from the registries: this file names no environment, algorithm or mode.
Reading a trained run back is [`taskrl.loading`][taskrl.loading]; several seeds of one setting, [`taskrl.seeds`][taskrl.seeds].
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path
from typing import Any

from rich.console import Console

from taskrl import config as config_io
from taskrl.assembly import build_parts
from taskrl.config import TrainConfig
from taskrl.console import ConsoleReporter, final_table, per_task_table
from taskrl.envs.registry import env_family
from taskrl.loading import evaluate_run, load, load_run
from taskrl.logger import RunLogger, require_wandb
from taskrl.overrides import with_overrides
from taskrl.plan import resolve
from taskrl.plots import plot_learning_curve
from taskrl.rundir import RunLock, check_new_run_dir
from taskrl.runmodes.registry import progress_axis
from taskrl.training.bookkeeping import Bookkeeping, LoopState, StopRequest
from taskrl.wiring.calls import (
    default_run_dir,
    env_source,
    import_env_module,
    print_notes,
    remember_compiled_graphs,
    resolve_config,
    run_title,
    settle_compile,
)
from taskrl.wiring.checkpoints import checkpointer, restore_checked, start_from_run
from taskrl.wiring.parts import EVAL_SEED_OFFSET, RunParts, make_agent, make_env, make_evaluator
from taskrl.wiring.stored_data import dataset_steps, preload_datasets, preload_replay

__all__ = ["Run", "RunParts", "build", "evaluate_run", "load", "load_run", "make_agent", "make_env", "train"]


@dataclasses.dataclass
class Run:
    """The result of `train`: where it was written, its settings, last metrics, and agent.

    Attributes:
        notes: what changing ``env`` or ``algo`` on a preset kept or dropped (also printed).
    """

    run_dir: Path
    config: TrainConfig
    metrics: dict[str, Any]
    agent: Any
    stopped_by: str | None = None  # "time limit", "SIGINT", "SIGTERM" when stopped early (resumable)
    notes: list[str] = dataclasses.field(default_factory=list)


def build(config: TrainConfig, source: Any = None) -> RunParts:
    """Envs, agent, replay, relabeller and sampler of a validated config, for the run mode it runs in
    (``source``: a Python object the env family builds its envs from, e.g. a factory or a TaskSet)."""
    return build_parts(resolve(config), source)


def train(
    preset: str | None = "bitflip-her",
    *,
    out: str | Path | None = None,
    resume: str | Path | None = None,
    progress: bool = False,
    tensorboard: bool = True,
    wandb: bool = False,
    console: Console | None = None,
    log_every: float = 0.0,
    base: TrainConfig | None = None,
    **overrides: Any,
) -> Run:
    """Train a preset (with overrides), or continue a run directory.

    Args:
        preset: name from ``taskrl presets``; ignored when resuming.
        out: run directory (default ``runs/<preset>-<timestamp>``); must not hold a run already.
        resume: a run directory to continue from its last checkpoint, with its saved settings
            (``overrides`` still apply, e.g. a larger ``total_steps``).
        progress: show a progress bar and print the final table.
        tensorboard: write TensorBoard events.
        wandb: also log metrics and settings to Weights & Biases (the ``wandb`` extra; offline, into the run
            directory, without an account or network: ``WANDB_MODE`` decides when set).
        console: where the final table and notes go (default stderr).
        log_every: without a terminal, also print a progress line every this many seconds between
            evaluations (0: one line per evaluation only).
        base: a full configuration to start from instead of the preset's (``--config FILE``).
        **overrides: any setting by name (``n_bits=30``, ``lr=1e-3``; see ``taskrl train PRESET --help``).
            ``env`` may also be a gymnasium id (``env="my/Slider-v0"``), a zero-argument factory
            of a ``gymnasium.Env``, or a [`TaskSet`][taskrl.tasks.TaskSet]; a run on a Python object
            needs the same ``env=`` again to resume (and to `load`).

    Returns:
        a `Run` with the run directory, configuration, final metrics and trained agent.
    """
    overrides = dict(overrides)
    source = env_source(overrides)
    notes: list[str] = []
    config = resolve_config(preset, resume, overrides, notes, base=base)
    if resume is not None:
        run_dir = Path(resume)
        saved = config_io.load(run_dir / "config.json")
    else:
        run_dir = check_new_run_dir(out if out is not None else default_run_dir(preset or "run"))
    if resume is None or "env_module" in overrides:  # a resumed run imports only what the caller names
        import_env_module(config.env_module)

    if wandb:  # before anything is written
        require_wandb()
    created = not run_dir.exists()
    lock = RunLock(run_dir, "resume" if resume is not None else "out")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        lock.__enter__()
        family = env_family(config.env)
        if source is not None and resume is None and family.persist is not None:  # record the object in the run
            config = with_overrides(config, family.persist(source, run_dir))
        plan = resolve(config)
        plan = dataclasses.replace(plan, config=settle_compile(plan.config, plan.algorithm, plan.family, notes))
        config, mode = plan.config, plan.mode
        parts = build_parts(plan, source)
        # A new run checkpoints after its first step (a kill before checkpoint_interval still resumes);
        # a resumed run loads its checkpoint before anything of it is rewritten.
        try:
            if resume is None and config.checkpoints.init_from:
                notes.append(start_from_run(parts, config.checkpoints.init_from))
            state = (
                LoopState(next_checkpoint=0, next_eval=0 if mode.evaluate_first else config.evaluation.eval_interval)
                if resume is None
                else restore_checked(parts, run_dir, saved, config)
            )
            # the stored data: a new run's, or a resumed --offline run's (its checkpoints leave the unchanging data out)
            if parts.replay is not None and parts.replay.num_episodes == 0:
                if config.data.offline_data:
                    preload_replay(parts, config.data.offline_data)
                if dataset_steps(config, parts.env):
                    preload_datasets(parts)
        except BaseException:
            parts.close()
            raise
    except BaseException:
        lock.__exit__()
        if created:  # nothing of this call stays behind
            shutil.rmtree(run_dir, ignore_errors=True)
        raise
    try:
        axis = mode.axis
        if resume is not None and state.progress(axis) >= config.total_steps:
            notes.append(
                f"the run is finished: {state.progress(axis):,} of total_steps {config.total_steps:,} {axis.replace('_', ' ')}; "
                f"to train on, extend it: taskrl train --resume {run_dir} --total-steps {2 * config.total_steps}"
            )
        print_notes(console, notes)
        config_io.save(config, run_dir / "config.json")
        at = state.progress(axis)
        tracking = {"name": run_dir.name, "config": config_io.to_dict(config)} if wandb else None
        logger = RunLogger(run_dir, tensorboard=tensorboard, resume_from_step=at if resume else None, axis=axis, wandb=tracking)
        rows: list[dict[str, Any]] = []
        title = run_title(run_dir, preset if resume is None else None, config)
        evaluator, last_eval = make_evaluator(
            config, parts.eval_env, parts.agent, config.seed + EVAL_SEED_OFFSET, family=parts.family
        )
        stop = StopRequest(config.max_hours)
        with ConsoleReporter(title, config.total_steps, at, enabled=progress, log_every=log_every, axis=axis) as reporter:

            def on_log(row: dict[str, Any]) -> None:
                rows.append(row)
                logger.log(row)
                reporter.update(row)

            books = Bookkeeping(
                state,
                evaluator,
                on_log,
                checkpointer(parts, run_dir, mode.axis),
                config.total_steps,
                config.evaluation.eval_interval,
                config.checkpoints.checkpoint_interval,
                config.evaluation.stop_at_success,
                parts.device,
                stop,
                checkpoint_seconds=60.0 * config.checkpoints.checkpoint_minutes,
                axis=axis,
            )
            books.heartbeat = reporter.heartbeat
            books.on_train_log, books.train_log_interval = logger.log_training, config.tensorboard_interval
            loop = mode.make_loop(parts, books)
            if parts.replay is not None:  # what the replay holds and has dropped
                books.row_metrics.append(lambda elapsed: parts.replay.metrics())
            if parts.sharing is not None:  # how much of each task's rows came from which task
                sharing, names = parts.sharing, list(parts.env.task_set.names)
                books.row_metrics.append(lambda elapsed: sharing.metrics(names))
            try:
                with stop.on_signals():
                    state = loop.run(env_seed=config.seed + state.env_steps)
                remember_compiled_graphs(config, parts.agent)  # a later run of these shapes compiles from the cache
            finally:
                logger.close()
                parts.close()
    finally:
        lock.__exit__()

    final = report(config, run_dir, title, rows, state, last_eval, logger.path, progress, console, stop)
    return Run(run_dir=run_dir, config=config, metrics=final, agent=parts.agent, stopped_by=stop.stopped_by, notes=notes)


def report(
    config: TrainConfig,
    run_dir: Path,
    title: str,
    rows: list[dict[str, Any]],
    state: LoopState,
    last_eval: dict[str, Any],
    metrics_csv: Path,
    progress: bool,
    console: Console | None,
    stop: StopRequest,
) -> dict[str, Any]:
    """The learning curve, the per-task result of multi-task runs, the final table; returns the last row."""
    out = console or Console(stderr=True)
    curve = plot_learning_curve(metrics_csv, run_dir / "learning_curve.png", title=f"{title} ({run_dir.name})")
    if last_eval:  # multi-task: the per-task table of the last evaluation, printed and saved
        at = {"env_steps": state.env_steps, "updates": state.updates}
        (run_dir / "per_task_success.json").write_text(json.dumps({**at, **last_eval}, indent=2) + "\n")
        if progress:
            out.print(per_task_table(last_eval, f"per-task success at {_progress_text(config, state)}"))
    final = (
        rows[-1]
        if rows
        else {
            "env_steps": state.env_steps,
            "updates": state.updates,
            "wall_seconds": state.wall_seconds,
            "success_rate": state.last_success,
        }
    )
    if progress:
        out.print(final_table({"eval_return": float("nan"), **final}, run_dir, curve))
    if stop.stopped_by:
        out.print(
            f"stopped early ({stop.stopped_by}) at {_progress_text(config, state)}, checkpoint saved; "
            f"continue with: taskrl train --resume {run_dir}",
            soft_wrap=True,
            markup=False,
        )
    return final


def _progress_text(config: TrainConfig, state: LoopState) -> str:
    if progress_axis(config) == "updates":
        return f"{state.updates:,} gradient updates"
    return f"{state.env_steps:,} env steps"
