"""``taskrl eval`` (a saved agent re-evaluated, or prompted with demonstrations) and ``taskrl export``."""

from __future__ import annotations

import argparse
import dataclasses
import json
from collections.abc import Sequence
from typing import Any

from taskrl.commands.parsing import (
    Parser,
    UsageError,
    parse,
)


def cmd_eval(argv: Sequence[str]) -> int:
    parser = Parser(prog="taskrl eval", description="Re-evaluate a saved agent: success with a 95% interval, per task.")
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
    parser.add_argument(
        "--cem",
        nargs="+",
        default=None,
        metavar="NAME=VALUE",
        help="act with another CEM search than the run's (QT-Opt), e.g. --cem samples=256 iterations=3 elites=24 "
        "(init_mean=0,0,-1,0: one value per action dimension)",
    )
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
    args = parse(parser, argv)
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
        cem=cem_changes(args.cem) if args.cem else None,
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


def cem_changes(items: Sequence[str]) -> dict[str, Any]:
    """``["samples=256", "init_mean=0,0,-1,0"]`` -> `CEMConfig` field changes, each value of its field's type."""
    from taskrl.agents.cem import CEMConfig

    defaults = dataclasses.asdict(CEMConfig())
    changes: dict[str, Any] = {}
    for item in items:
        name, _, text = item.partition("=")
        name = name.strip().replace("-", "_")
        if name not in defaults or not text:
            raise UsageError(f"--cem takes NAME=VALUE with NAME one of {', '.join(defaults)} (got {item!r})")
        kind = type(defaults[name])
        try:
            if kind is tuple:
                changes[name] = tuple(float(v) for v in text.split(","))
            elif kind is bool:
                changes[name] = {"true": True, "false": False}[text.lower()]
            else:
                changes[name] = kind(text)
        except (ValueError, KeyError):
            raise UsageError(
                f"--cem {name} must be {kind.__name__ if kind is not tuple else 'numbers separated by commas'} (got {text!r})"
            ) from None
    return changes


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
    parser = Parser(prog="taskrl export", description="Write what acting needs (weights, normaliser, spaces, settings).")
    parser.add_argument("run_dir", help="a run directory written by `taskrl train`")
    parser.add_argument("--out", required=True, help="a new or empty directory for policy.safetensors and policy.json")
    parser.add_argument("--env-module", default=None, help="import this module first (one that registers the run's gymnasium id)")
    args = parse(parser, argv)
    from taskrl.export import export_policy

    out = export_policy(args.run_dir, args.out, env_module=args.env_module)
    size = sum(f.stat().st_size for f in out.iterdir())
    print(f"policy written to {out} ({size / 1024:.0f} KiB); load it with taskrl.load_policy({str(out)!r})")
    return 0
