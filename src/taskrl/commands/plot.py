"""``taskrl plot``: runs compared, mean and 95% band over seeds."""

from __future__ import annotations

from collections.abc import Sequence

from taskrl.commands.parsing import (
    Parser,
    UsageError,
    parse,
)


def cmd_plot(argv: Sequence[str]) -> int:
    parser = Parser(prog="taskrl plot", description="Compare runs: success (mean and 95% band over seeds), return, per task.")
    parser.add_argument("runs", nargs="+", help="run directories, or folders of them (one line per folder: its seeds)")
    parser.add_argument("--out", required=True, help="the PNG to write (the summary goes beside it as .csv)")
    parser.add_argument("--threshold", type=float, default=0.9, help="success rate whose env steps and time are reported")
    args = parse(parser, argv)
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
