"""The ``taskrl`` command line.

    taskrl presets                         list presets with a one-line description each
    taskrl train PRESET [--setting VALUE]  train (every setting of the run, its env and its algorithm is a flag)
    taskrl train PRESET --env-id my/Env-v0 train a preset's algorithm on any gymnasium env (--env-module to register it)
    taskrl train --resume RUN_DIR          continue a run from its last checkpoint
    taskrl eval RUN_DIR                    re-evaluate a saved agent (--json, --video N, --checkpoint STEP)
    taskrl export RUN_DIR --out DIR        write the policy alone (taskrl.load_policy(DIR).predict(obs))
    taskrl train PRESET --seeds 0 1 2      one run per seed into one folder (--parallel N), then compared
    taskrl plot RUN_OR_FOLDER ... --out F  compare runs: mean and 95% band over seeds, per task, a table
    taskrl solve MDP [--method ...]        exact dynamic programming on finite MDPs
    taskrl demos collect SOURCE --out DIR  scripted-expert demonstrations (mt10, mt50, ml45, pointreach-mt) as a Minari dataset
    taskrl demos info DIR                  a demonstration dataset's card

Bad input exits with code 2 and one line naming the setting and the allowed values.
"""

from __future__ import annotations

import argparse
import difflib
import json
import re
import sys
import typing
from collections.abc import Sequence
from typing import Any

COMMANDS = ("train", "eval", "export", "plot", "presets", "solve", "demos")
POSITIONAL = ("preset", "run_dir", "source")
#: Errors about files rather than settings: named as they are, not as flags.
FILES = {"config": "config.json:", "config_file": "--config", "checkpoint": "checkpoint:", "policy": "policy:"}
_NUMBER = re.compile(r"-(\d+\.?\d*|\.\d+)(e[-+]?\d+)?", re.IGNORECASE)


def _numbers_as_values(argv: Sequence[str]) -> list[str]:
    """``--lr -1e-3`` -> ``--lr=-1e-3``: argparse would read a negative number in exponent form as a flag."""
    out: list[str] = []
    for token in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and _NUMBER.fullmatch(token):
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


class UsageError(Exception):
    """Bad command-line input: printed as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__(allow_abbrev=False, **kwargs)

    def error(self, message: str) -> typing.NoReturn:
        raise UsageError(message)


#: whole-number settings whose 0 means "the library chooses", given as ``auto`` on the command line
_AUTO_COUNTS = {"updates_per_call"}


def _count_or_auto(text: str) -> int:
    if text == "auto":
        return 0
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number or auto, got {text!r}") from None


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def terminal_text(markup: str) -> str:
    """A docstring's markup as a terminal shows it: ````code```` and `` `code` `` as the code, cross-references
    ``[`name`][taskrl.path]`` as the name."""
    text = re.sub(r"\[`([^`]+)`\]\[[\w.]+\]", r"\1", markup)
    return re.sub(r"``?([^`]+)``?", r"\1", text)


def _add_config_flags(parser: argparse.ArgumentParser, env: str, algo: str, base: Any = None) -> dict[str, list[str]]:
    """One flag per setting, in sections (``--algo.lr``, ``--env.n-bits``, ``--algo.cem.samples``,
    ``--data-sharing.share-fraction``), each also under its short name (``--lr``) where no other setting
    has it; the ``dest`` is the dotted name [`taskrl.overrides.with_overrides`][taskrl.overrides.with_overrides] reads. Returns the
    ambiguous short names (``{short flag: [its dotted flags]}``) for the error that names them."""
    from taskrl.agents.registry import ALGORITHMS
    from taskrl.config import to_dict
    from taskrl.envs.registry import ENV_FAMILIES
    from taskrl.setting_names import dotted_name, leaf_fields, setting_help, setting_names
    from taskrl.sharing.registry import SHARING_STRATEGIES

    docs = setting_help(env, algo)
    names = setting_names(env, algo)
    values = to_dict(base) if base is not None and base.env == env and base.algo == algo else {}
    docs[("env",)] += " Choices: " + "; ".join(f"{f.name} ({f.description})" for f in ENV_FAMILIES.values())
    docs[("algo",)] += " Choices: " + "; ".join(f"{a.name} ({a.description})" for a in ALGORITHMS.values())
    choices = {"env": tuple(ENV_FAMILIES), "algo": tuple(ALGORITHMS), "sharing": tuple(SHARING_STRATEGIES)}
    family = ENV_FAMILIES[env]
    titles = {
        "conditioning": "task conditioning (multi-task networks)",
        "cluster": "where the roles run (--distributed)",
        "data_sharing": "data sharing between tasks",
        family.section: f"env family '{env}' (--env.* flags, {family.section} section)",
        algo: f"algorithm '{algo}' (--algo.* flags, {algo} section)",
    }
    groups: dict[str, Any] = {}
    for path, _field, tp in leaf_fields(env, algo):
        section = path[0] if len(path) > 1 else "run"
        if section not in groups:  # one block per section of config.json, so --help reads as the reference does
            groups[section] = parser.add_argument_group(f"settings: {titles.get(section, 'run')}")
        name, dotted = path[-1], dotted_name(path, env, algo)
        text = terminal_text(docs.get(path, "")).replace("%", "%%")
        node: Any = values
        for key in path:
            node = node.get(key, {}) if isinstance(node, dict) else {}
        if values and not isinstance(node, dict):  # this run's value (the preset's, or the resumed run's)
            shown = " ".join(map(str, node)) if isinstance(node, list) else node
            text += f" [here: {shown}]"
        kwargs: dict[str, Any] = {"dest": dotted, "default": argparse.SUPPRESS, "help": text}
        origin = typing.get_origin(tp)
        if name in choices and len(path) == 1 or path == ("data_sharing", "sharing"):
            kwargs["choices"] = choices[name]
        elif tp is bool:
            kwargs["action"] = argparse.BooleanOptionalAction
        elif origin is typing.Literal:
            kwargs["choices"] = typing.get_args(tp)
        elif origin is tuple:
            kwargs.update(type=int, nargs="+", metavar="N")
        elif name in _AUTO_COUNTS:
            kwargs.update(type=_count_or_auto, metavar="{N,auto}")
        else:
            kwargs["type"] = tp
        if "choices" not in kwargs and "action" not in kwargs and "metavar" not in kwargs:
            kwargs["metavar"] = name.upper()
        flags = [_flag(dotted)] if "." in dotted else []
        if names.paths.get(name) == path:
            flags.append(_flag(name))
        groups[section].add_argument(*flags, **kwargs)
    return {_flag(short): [_flag(d) for d in dotted] for short, dotted in names.ambiguous.items()}


def _config_file(argv: Sequence[str]) -> tuple[dict[str, Any], Any]:
    """``(settings by name, full config or None)`` from ``--config FILE``: a full config (a run's
    config.json, or what --print-config printed) becomes the starting point; a mapping of settings
    by name (``lr: 0.001``) is applied like flags, before them."""
    peek = _Parser(add_help=False)
    peek.add_argument("--config")
    known, _ = peek.parse_known_args(argv)
    if known.config is None:
        return {}, None
    from pathlib import Path

    from taskrl.config import from_dict
    from taskrl.errors import ConfigError
    from taskrl.files import read_data_file

    path = Path(known.config)
    try:
        data = read_data_file(path)
    except ValueError as error:
        raise ConfigError("config_file", str(error)) from None
    if not isinstance(data, dict):
        raise ConfigError("config_file", f"{path} must hold a mapping of settings")
    if any(isinstance(v, dict) for v in data.values()):  # sections: a full config
        return {}, from_dict(data)
    return {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}, None


def _active_sections(argv: Sequence[str], file_base: Any = None, file_settings: dict | None = None) -> tuple[str, str, Any]:
    """``(env, algo)`` whose settings the flags address: ``--env`` / ``--algo`` (``--env-id`` or
    ``--task-file`` alone select their family), else the preset's, else the resumed run's."""
    from taskrl.agents.registry import ALGORITHMS
    from taskrl.config import TrainConfig
    from taskrl.envs.registry import ENV_FAMILIES
    from taskrl.presets import PRESETS, preset_config

    peek = _Parser(add_help=False)
    peek.add_argument("preset", nargs="?")
    peek.add_argument("--env")
    peek.add_argument("--algo")
    peek.add_argument("--resume")
    selectors = {f.selected_by: f.name for f in ENV_FAMILIES.values() if f.selected_by}
    for setting in selectors:
        peek.add_argument(_flag(setting))
    peek.add_argument("--env-module")
    known, _ = peek.parse_known_args(argv)
    if known.env_module:  # it may register env families and algorithms the flags below name
        from taskrl.wiring.calls import import_env_module

        import_env_module(known.env_module)
    for flag, value, allowed in (("--env", known.env, ENV_FAMILIES), ("--algo", known.algo, ALGORITHMS)):
        if value is not None and value not in allowed:
            hint = " (a gymnasium id goes to --env-id)" if flag == "--env" else ""
            raise UsageError(f"argument {flag}: invalid choice: {value!r} (choose from {', '.join(map(repr, allowed))}){hint}")
    base = TrainConfig()
    if file_base is not None:
        base = file_base
    elif known.preset in PRESETS:
        base = preset_config(known.preset)
    elif known.resume is not None:
        from pathlib import Path

        from taskrl.config import load
        from taskrl.errors import ConfigError

        saved = Path(known.resume) / "config.json"
        if saved.exists():
            try:
                base = load(saved)
            except ConfigError:
                pass  # train() reports a damaged config.json in one line
    env = known.env or (file_settings or {}).get("env")
    known.algo = known.algo or (file_settings or {}).get("algo")
    if env is None:
        given = [name for setting, name in selectors.items() if getattr(known, setting) is not None]
        env = given[0] if given and given[0] != base.env else base.env
    return env, known.algo or base.algo, base


def _parse(
    parser: argparse.ArgumentParser, argv: Sequence[str], ambiguous: dict[str, list[str]] | None = None
) -> argparse.Namespace:
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        flags = sorted(f for a in parser._actions for f in a.option_strings if f.startswith("--"))
        bad = unknown[0]
        spelled = bad.split("=")[0].replace("--no-", "--")
        if ambiguous and spelled in ambiguous:
            raise UsageError(f"{spelled} is a setting of several sections here: say {' or '.join(ambiguous[spelled])}")
        close = difflib.get_close_matches(bad.split("=")[0], flags, n=1)
        hint = f" (did you mean {close[0]}?)" if close else ""
        raise UsageError(f"unknown option {bad!r}{hint}; allowed: {', '.join(flags)}")
    return args


def cmd_presets(argv: Sequence[str]) -> int:
    from taskrl.presets import PRESETS

    _parse(_Parser(prog="taskrl presets", description="List the training presets."), argv)
    width = max(len(n) for n in PRESETS)
    for name, preset in PRESETS.items():
        print(f"{name:<{width}}  {preset.description}")
    return 0


def cmd_train(argv: Sequence[str]) -> int:
    from taskrl.presets import PRESETS

    parser = _Parser(prog="taskrl train", description="Train an agent from a preset; every setting below overrides it.")
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
    argv = _numbers_as_values(argv)
    file_settings, file_base = _config_file(argv)
    env, algo, base = _active_sections(argv, file_base, file_settings)
    ambiguous = _add_config_flags(parser, env, algo, base)
    args = vars(_parse(parser, argv, ambiguous))
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


def cmd_eval(argv: Sequence[str]) -> int:
    parser = _Parser(prog="taskrl eval", description="Re-evaluate a saved agent: success with a 95% interval, per task.")
    parser.add_argument("run_dir", help="a run directory written by `taskrl train`")
    parser.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="evaluation episodes, per task on multi-task envs (default 100; 50 with --held-out, --tasks or --task, "
        "as many as Meta-World has goal positions per task)",
    )
    parser.add_argument("--seed", type=int, default=None, help="evaluation seed (default: the run's evaluation seed)")
    parser.add_argument("--device", default="cpu", help="cpu, cuda, cuda:N or auto")
    parser.add_argument(
        "--checkpoint", type=int, default=None, metavar="STEP", help="the checkpoint of this env step (default the latest)"
    )
    parser.add_argument("--stochastic", action="store_true", help="act with the algorithm's exploration, not greedily")
    parser.add_argument("--video", type=int, default=0, metavar="N", help="also record N episodes to RUN_DIR/videos/ (MP4)")
    parser.add_argument("--json", action="store_true", help="print one line of JSON instead of tables")
    parser.add_argument("--env-module", default=None, help="import this module first (one that registers the run's gymnasium id)")
    prompted = parser.add_argument_group("prompted policies (--algo bc with language or demo input)")
    prompted.add_argument(
        "--held-out",
        action="store_true",
        help="evaluate the run's held-out tasks, zero-shot; on a family with held-out objects (grasp), on those objects",
    )
    prompted.add_argument(
        "--tasks", default=None, metavar="NAME,NAME", help="evaluate these tasks of the run's family, zero-shot"
    )
    prompted.add_argument(
        "--task", default=None, metavar="SENTENCE", help="evaluate the task this sentence names, prompted with it"
    )
    prompted.add_argument(
        "--prompt",
        default="description",
        help="description, paraphrase or demo (default description); the controls: none (a null prompt) and "
        "other-task (each task prompted as another evaluated one)",
    )
    prompted.add_argument("--dataset", default=None, help="demonstrations for --prompt demo (default the run's dataset)")
    args = _parse(parser, argv)
    if args.episodes is not None and args.episodes < 1:
        raise UsageError(f"--episodes must be >= 1 (got {args.episodes})")
    if args.video < 0:
        raise UsageError(f"--video must be >= 0 episodes (got {args.video})")
    if args.task is not None and not args.task.strip():
        raise UsageError("--task must be a sentence that describes a task (got an empty one)")
    if args.tasks is not None and not [n for n in args.tasks.split(",") if n.strip()]:
        raise UsageError("--tasks must name tasks of the run's family, separated by commas (got none)")
    from taskrl.loading import evaluate_run, held_out_objects

    objects = args.held_out and not (args.tasks or args.task) and held_out_objects(args.run_dir)
    if (args.held_out and not objects) or args.tasks or args.task:
        return _eval_prompted(args)

    result = evaluate_run(
        args.run_dir,
        100 if args.episodes is None else args.episodes,
        args.seed,
        args.device,
        env_module=args.env_module,
        checkpoint=args.checkpoint,
        stochastic=args.stochastic,
        video=args.video,
        held_out=bool(objects),
    )
    if args.json:
        print(json.dumps(result))
        return 0
    from rich.console import Console

    from taskrl.console import eval_table, per_task_table

    out = Console()
    if "tasks" in result:
        out.print(
            per_task_table(
                {"tasks": result["tasks"], "mean_success_rate": result["success_rate"]},
                f"per-task success, checkpoint at {result['checkpoint_step']:,} {result.get('checkpoint_unit', 'env steps')}",
            )
        )
    out.print(eval_table(result, args.run_dir))
    for path in result.get("videos", []):
        out.print(f"video: {path}", soft_wrap=True, markup=False)
    return 0


def _eval_prompted(args: argparse.Namespace) -> int:
    from rich.console import Console

    from taskrl.console import per_task_table
    from taskrl.prompting import evaluate_prompted

    if sum(bool(x) for x in (args.held_out, args.tasks, args.task)) > 1:
        raise UsageError("choose one of --held-out, --tasks and --task")
    tasks = [n.strip() for n in args.tasks.split(",") if n.strip()] if args.tasks else None
    result = evaluate_prompted(
        args.run_dir,
        tasks,
        sentence=args.task,
        prompt=args.prompt,
        dataset=args.dataset,
        episodes=50 if args.episodes is None else args.episodes,
        seed=args.seed,
        device=args.device,
    )
    if args.json:
        print(json.dumps(result))
        return 0
    out = Console()
    if "matched" in result:
        m = result["matched"]
        out.print(f"the sentence names {m['task']!r} (cosine {m['cosine']:.2f}); prompted with the sentence itself", markup=False)
    lo, hi = result["success_ci95"]
    out.print(
        per_task_table(
            {"tasks": result["tasks"], "mean_success_rate": result["success_rate"]}, f"zero-shot, prompted by {result['prompt']}"
        )
    )
    out.print(
        f"success {result['success_rate']:.3f} (95% interval {lo:.3f} - {hi:.3f}), {result['episodes']} episodes per task",
        markup=False,
    )
    return 0


def cmd_export(argv: Sequence[str]) -> int:
    parser = _Parser(prog="taskrl export", description="Write what acting needs (weights, normaliser, spaces, settings).")
    parser.add_argument("run_dir", help="a run directory written by `taskrl train`")
    parser.add_argument("--out", required=True, help="a new or empty directory for policy.safetensors and policy.json")
    parser.add_argument("--env-module", default=None, help="import this module first (one that registers the run's gymnasium id)")
    args = _parse(parser, argv)
    from taskrl.export import export_policy

    out = export_policy(args.run_dir, args.out, env_module=args.env_module)
    size = sum(f.stat().st_size for f in out.iterdir())
    print(f"policy written to {out} ({size / 1024:.0f} KiB); load it with taskrl.load_policy({str(out)!r})")
    return 0


def cmd_plot(argv: Sequence[str]) -> int:
    parser = _Parser(prog="taskrl plot", description="Compare runs: success (mean and 95% band over seeds), return, per task.")
    parser.add_argument("runs", nargs="+", help="run directories, or folders of them (one line per folder: its seeds)")
    parser.add_argument("--out", required=True, help="the PNG to write (the summary goes beside it as .csv)")
    parser.add_argument("--threshold", type=float, default=0.9, help="success rate whose env steps and time are reported")
    args = _parse(parser, argv)
    from pathlib import Path

    from rich.console import Console

    from taskrl.console import summary_table
    from taskrl.plots import PLOT_FORMATS, RUN_COLUMNS, compare_runs, find_runs

    if Path(args.out).suffix.lower() not in PLOT_FORMATS:
        raise UsageError(f"--out must name an image file ending in {', '.join(PLOT_FORMATS)} (got {args.out})")
    groups = {}
    for path in args.runs:
        found = find_runs(path)
        if not found:
            raise UsageError(
                f"{path} is not a run directory and holds none (no metrics.csv with the columns {', '.join(RUN_COLUMNS)})"
            )
        groups[Path(path).name or str(path)] = found
    summary = compare_runs(groups, Path(args.out), args.threshold)
    Console().print(summary_table(summary))
    print(f"plot: {args.out}  table: {Path(args.out).with_suffix('.csv')}")
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


def cmd_demos(argv: Sequence[str]) -> int:
    parser = _Parser(
        prog="taskrl demos",
        description="Demonstration datasets: collect with scripted experts, correct a policy (HG-DAgger), merge, show a card.",
    )
    sub = parser.add_subparsers(dest="action", required=True, metavar="{collect,dagger,merge,info}")
    collect = sub.add_parser("collect", help="run scripted experts and write their successful episodes (resumable)")
    from taskrl.demos.experts import demo_sources

    collect.add_argument(
        "source",
        help=f"a family with a scripted expert ({', '.join(demo_sources())}; ml45: all 50 tasks, its split in the card), "
        "FAMILY:task,task, or Meta-World task,task,...",
    )
    collect.add_argument("--out", required=True, help="dataset folder (DIR/data is the Minari dataset); run again to resume")
    collect.add_argument("--episodes", type=int, default=50, help="successful episodes per task (default 50)")
    collect.add_argument("--noise", type=float, default=0.0, help="std of Gaussian noise on executed actions (DART; default 0)")
    collect.add_argument("--seed", type=int, default=1, help="seed of goals and noise (default 1)")
    collect.add_argument("--copies", type=int, default=1, help="env copies per task (default 1)")
    collect.add_argument("--max-attempts", type=int, default=0, help="episodes a task may try (default 5 x --episodes)")
    collect.add_argument(
        "--after-success", type=int, default=10, help="Meta-World: steps kept after the first success (default 10)"
    )
    collect.add_argument(
        "--pictures",
        type=int,
        default=0,
        metavar="SIZE",
        help="also record each state's rendered picture, SIZE x SIZE (Meta-World; train on them with --observation "
        "pixels or pixels+state); tabletop always records its camera, at SIZE where given (default 32)",
    )
    collect.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    dagger = sub.add_parser(
        "dagger",
        help="HG-DAgger: a trained policy acts, the scripted expert takes over when it drifts; its corrections are the dataset",
    )
    dagger.add_argument("run_dir", help="a run trained on a family with a scripted expert")
    dagger.add_argument("--out", required=True, help="folder of the corrections' dataset")
    dagger.add_argument("--episodes", type=int, default=10, help="episodes per task (default 10)")
    dagger.add_argument(
        "--threshold", type=float, default=0.3, help="RMS action disagreement above which the policy drifts (default 0.3)"
    )
    dagger.add_argument(
        "--patience", type=int, default=3, help="consecutive steps above (take over) or below (hand back) it (default 3)"
    )
    dagger.add_argument("--seed", type=int, default=2, help="seed of the goals (default 2)")
    dagger.add_argument("--after-success", type=int, default=10, help="steps an episode goes on after success (default 10)")
    dagger.add_argument("--device", default="cpu", help="where the policy runs (default cpu)")
    dagger.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    merge = sub.add_parser("merge", help="one dataset of several datasets' episodes (e.g. demonstrations and corrections)")
    merge.add_argument("datasets", nargs="+", help="dataset folders, in order")
    merge.add_argument("--out", required=True, help="folder of the merged dataset")
    merge.add_argument("--max-steps", type=int, default=None, help="keep only the first episodes up to this many steps")
    info = sub.add_parser("info", help="print a dataset's card")
    info.add_argument("dataset", help="a dataset folder")
    info.add_argument("--json", action="store_true", help="print the metadata as JSON")
    args = _parse(parser, argv)
    from rich.console import Console

    from taskrl.console import dataset_table
    from taskrl.demos.dataset import dataset_card

    if args.action == "info":
        from taskrl.errors import ConfigError

        try:
            card = dataset_card(args.dataset)
        except ConfigError as error:  # the folder is the positional argument, not a --dataset flag
            raise UsageError(error.message) from None
        if args.json:
            print(json.dumps(card))
        else:
            Console().print(dataset_table(card, args.dataset))
        return 0
    from taskrl.console import CollectionProgress

    if args.action == "merge":
        from taskrl.demos.dagger import merge_datasets

        Console().print(dataset_table(merge_datasets(args.datasets, args.out, args.max_steps), args.out))
        return 0
    if args.action == "dagger":
        from taskrl.demos.dagger import InterventionRule, collect_interventions

        with CollectionProgress(f"hg-dagger {args.run_dir}", enabled=args.progress) as bar:
            card = collect_interventions(
                args.run_dir,
                args.out,
                episodes=args.episodes,
                rule=InterventionRule(args.threshold, args.patience),
                seed=args.seed,
                after_success=args.after_success,
                device=args.device,
                progress=bar.update,
            )
        expert, policy = card["expert_steps_total"], card["policy_steps_total"]
        print(
            f"expert drove {expert:,} of {expert + policy:,} steps in {sum(card['interventions'].values())} interventions"
            + (f"; corrections written to {args.out}" if expert else "; it never took over, nothing written")
        )
        return 0
    from taskrl.demos.collect import collect_demos

    with CollectionProgress(f"demos {args.source}", enabled=args.progress) as bar:
        card = collect_demos(
            args.source,
            args.episodes,
            args.out,
            seed=args.seed,
            noise_std=args.noise,
            copies=args.copies,
            max_attempts=args.max_attempts,
            after_success=args.after_success,
            pictures=args.pictures,
            progress=bar.update,
        )
    Console().print(dataset_table(card, args.out))
    return 0


def cmd_solve(argv: Sequence[str]) -> int:
    from taskrl.tabular.cli import main as solve_main

    return solve_main(list(argv))


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        return 0
    command, rest = argv[0], argv[1:]
    handlers = {
        "train": cmd_train,
        "eval": cmd_eval,
        "export": cmd_export,
        "plot": cmd_plot,
        "presets": cmd_presets,
        "solve": cmd_solve,
        "demos": cmd_demos,
    }
    from taskrl.distributed.loop import RolesLost
    from taskrl.distributed.pools import RoleCannotStart
    from taskrl.errors import ConfigError
    from taskrl.training.bookkeeping import TrainingDiverged

    try:
        if command not in handlers:
            raise UsageError(f"unknown command {command!r}; allowed: {', '.join(COMMANDS)}")
        return handlers[command](rest)
    except UsageError as e:
        print(f"taskrl {command}: error: {e}", file=sys.stderr)
        return 2
    except ConfigError as e:
        label = e.field.upper() if e.field in POSITIONAL else FILES.get(e.field, _flag(e.field))
        print(f"taskrl {command}: error: {label} {e.message}", file=sys.stderr)
        return 2
    except (FileNotFoundError, NotADirectoryError, IsADirectoryError, PermissionError) as e:
        print(f"taskrl {command}: error: {e}", file=sys.stderr)
        return 2
    except ImportError as e:  # an optional extra not installed, named where taskrl knows it (ConfigError above)
        print(
            f"taskrl {command}: error: a package is missing ({e}); the optional extras install with: "
            "pip install -e '.[robotics,language,metaworld,video,imitation,distributed]'",
            file=sys.stderr,
        )
        return 2
    except (TrainingDiverged, RolesLost, RoleCannotStart) as e:
        print(f"taskrl {command}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:  # a second Ctrl-C: the last complete checkpoint stays
        print(f"taskrl {command}: aborted; the run's last complete checkpoint is intact", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
