"""``taskrl presets`` and ``taskrl train`` (one run, a resumed one, or one per seed)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

from taskrl.commands.parsing import (
    Parser,
    UsageError,
    active_sections,
    add_config_flags,
    config_file,
    numbers_as_values,
    parse,
)


def cmd_presets(argv: Sequence[str]) -> int:
    from taskrl.presets import PRESETS

    parse(Parser(prog="taskrl presets", description="List the training presets."), argv)
    width = max(len(n) for n in PRESETS)
    for name, preset in PRESETS.items():
        print(f"{name:<{width}}  {preset.description}")
    return 0


def cmd_train(argv: Sequence[str]) -> int:
    from taskrl.presets import PRESETS

    parser = Parser(prog="taskrl train", description="Train an agent from a preset; every setting below overrides it.")
    parser.add_argument("preset", nargs="?", choices=list(PRESETS), help="preset name (see `taskrl presets`)")
    parser.add_argument("--out", help="run directory (default runs/<preset>-<timestamp>)")
    parser.add_argument("--resume", metavar="RUN_DIR", help="continue this run from its last checkpoint")
    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=True, help="progress bar and final table")
    parser.add_argument("--tensorboard", action=argparse.BooleanOptionalAction, default=True, help="write TensorBoard events")
    parser.add_argument(
        "--wandb",
        action="store_true",
        help="also log to Weights & Biases (the wandb extra; offline into the run directory without an account)",
    )
    parser.add_argument(
        "--log-every",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="without a terminal, also print a progress line every SECONDS between evaluations",
    )
    parser.add_argument("--seeds", type=int, nargs="+", metavar="S", help="one run per seed into OUT/seed_S, then a comparison")
    parser.add_argument("--parallel", type=int, default=1, metavar="N", help="with --seeds: N runs at once (processes)")
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="settings from a YAML or JSON file (a run's config.json, or a mapping of settings by name); flags override them",
    )
    parser.add_argument("--print-config", action="store_true", help="print the resolved settings as JSON and exit")
    argv = numbers_as_values(argv)
    file_settings, file_base = config_file(argv)
    env, algo, sharing, base = active_sections(argv, file_base, file_settings)
    ambiguous = add_config_flags(parser, env, algo, base, sharing)
    args = vars(parse(parser, argv, ambiguous))
    args.pop("config")
    print_config = args.pop("print_config")
    preset, out, resume = args.pop("preset"), args.pop("out"), args.pop("resume")
    progress, tensorboard, log_every = args.pop("progress"), args.pop("tensorboard"), args.pop("log_every")
    wandb = args.pop("wandb")
    if log_every < 0:
        raise UsageError(f"--log-every must be >= 0 seconds (got {log_every})")
    if preset is None and resume is None and file_base is None:
        raise UsageError(f"a preset is required unless --resume is given; allowed: {', '.join(PRESETS)}")
    if preset is not None and resume is not None:
        raise UsageError(f"give a preset (a new run) or --resume {resume} (its own settings), not both")
    if resume is not None and out is not None:
        raise UsageError("--out does not apply with --resume (a run continues in its own directory)")
    seeds, parallel = args.pop("seeds"), args.pop("parallel")
    args = {k: tuple(v) if isinstance(v, list) else v for k, v in args.items()}  # nargs="+" settings are tuples
    args = {**file_settings, **args}  # flags override the file
    if seeds is not None:
        if preset is None or resume is not None:
            raise UsageError("--seeds starts new runs of a preset (resume each seed's run directory on its own)")
        if print_config:
            raise UsageError("--print-config prints one run's settings; drop --seeds")
        return _train_seeds(preset, seeds, parallel, out, progress, tensorboard, wandb, log_every, file_base, args)

    from taskrl.run import train
    from taskrl.wiring.calls import resolve_config

    if print_config:
        from taskrl.config import to_dict
        from taskrl.plan import validate

        notes: list[str] = []
        resolved = validate(resolve_config(preset, resume, args, notes, base=file_base))
        for line in notes:
            print(line if line.startswith("warning: ") else f"note: {line}", file=sys.stderr)
        print(json.dumps(to_dict(resolved), indent=2))
        return 0

    run = train(
        preset,
        out=out,
        resume=resume,
        progress=progress,
        tensorboard=tensorboard,
        wandb=wandb,
        log_every=log_every,
        base=file_base,
        **args,
    )
    if not progress:
        print(json.dumps({"run_dir": str(run.run_dir), **run.metrics}))
    return 0


def _train_seeds(
    preset: str,
    seeds: list[int],
    parallel: int,
    out: str | None,
    progress: bool,
    tensorboard: bool,
    wandb: bool,
    log_every: float,
    base: Any,
    settings: dict[str, Any],
) -> int:
    """``--seeds``: [`taskrl.seeds.train_seeds`][taskrl.seeds.train_seeds], its comparison table and where it wrote."""
    from rich.console import Console

    from taskrl.console import summary_table
    from taskrl.seeds import train_seeds

    if "seed" in settings:
        raise UsageError("give --seeds or --seed, not both")
    result = train_seeds(
        preset,
        seeds,
        out=out,
        parallel=parallel,
        progress=progress and parallel == 1,
        base=base,
        tensorboard=tensorboard,
        wandb=wandb,
        log_every=log_every,
        **settings,
    )
    if result.runs and not (progress and parallel == 1):
        Console(stderr=True).print(summary_table(result.summary, f"{preset}: {len(result.runs)} seeds"))
    if result.plot is not None:
        print(f"runs: {result.folder}  plot: {result.plot}")
    if result.failed:
        for seed, error in result.failed.items():
            print(f"taskrl train: error: seed {seed}: {error}", file=sys.stderr)
        return 1
    return 0
