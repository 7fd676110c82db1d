"""``taskrl demos``: collect, correct (HG-DAgger), merge and describe demonstration datasets."""

from __future__ import annotations

import json
from collections.abc import Sequence

from taskrl.commands.parsing import (
    Parser,
    UsageError,
    parse,
)


def cmd_demos(argv: Sequence[str]) -> int:
    parser = Parser(
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
    args = parse(parser, argv)
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
        from taskrl.loading import load_run

        with CollectionProgress(f"hg-dagger {args.run_dir}", enabled=args.progress) as bar:
            card = collect_interventions(
                load_run(args.run_dir, args.device),
                args.out,
                run_name=str(args.run_dir),
                episodes=args.episodes,
                rule=InterventionRule(args.threshold, args.patience),
                seed=args.seed,
                after_success=args.after_success,
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
