"""PixelPush's goal pictures from one distribution: SAC + HER from pictures before and after the change.

Before, hindsight relabelled a goal picture with the picture of the moment the block was there (the pusher usually
touching it), while the env's own goal pictures showed the pusher at a random spot out of the way; now both are the
block alone, drawn by the env (``PixelPush.goal_picture``). This compares the runs of ``pixelpush-sac-her`` made
before (their curves in an earlier raw file of ``pixel_goals.py``) with runs made after (``taskrl train
pixelpush-sac-her --seed S --stop-at-success 0.9 --threads 1 --out AFTER/pictures-sS``), seed by seed.

    .venv/bin/python benchmarks/goal_picture_distribution.py --after /work/runs-bench/pixel-push-goalfix --seeds 0 --write
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HERE = Path(__file__).resolve().parent
TARGET = 0.9


def reached(curve: list[tuple[int, float]]) -> int | None:
    return next((steps for steps, success in curve if success >= TARGET), None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", type=Path, default=HERE / "results" / "pixel_goals_push.json")
    parser.add_argument("--after", type=Path, required=True, help="folder of the runs made after (pictures-sS)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--after-commit", default="", help="the commit the runs after were made at")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    from taskrl.logger import read_metrics

    before = {r["seed"]: r for r in json.loads(args.before.read_text()) if r["arm"] == "pictures"}
    rows, raw = [], []
    for seed in args.seeds:
        old = [(int(c["env_steps"]), c["success_rate"]) for c in before[seed]["curve"]]
        metrics = read_metrics(args.after / f"pictures-s{seed}" / "metrics.csv")
        new = [(int(r["env_steps"]), r["success_rate"]) for r in metrics if r["success_rate"] is not None]
        raw.append({"seed": seed, "before": old, "after": new})
        marks = sorted({s for s, _ in new if s % 10_000 == 0 and s > 0})
        cells = " / ".join(f"{dict(old).get(m, float('nan')):.2f} -> {dict(new)[m]:.2f}" for m in marks)
        before_steps, after_steps = reached(old), reached(new)
        rows.append(
            f"| {seed} | {before_steps:,} | {after_steps:,} | {cells} |"
            if before_steps and after_steps
            else f"| {seed} | {before_steps} | {after_steps} | {cells} |"
        )
    marks_head = " / ".join(f"{m // 1000}k" for m in marks)
    text = (
        f"`pixelpush-sac-her` from pictures, before (hindsight goal pictures showed the pusher where it was; raw: "
        f"`{args.before.relative_to(HERE.parent) if args.before.is_relative_to(HERE.parent) else args.before}`) and "
        f"after (goal pictures of the block alone, the env's and hindsight's alike"
        f"{', runs at commit ' + args.after_commit if args.after_commit else ''}); one torch thread per run, the "
        f"after runs with other benchmarks on the cores. Raw data: `benchmarks/results/goal_picture_distribution.json`.\n\n"
        f"| seed | env steps to 0.9, before | after | success before -> after at {marks_head} |\n|---|---|---|---|\n"
        + "\n".join(rows)
    )
    print(text)
    if args.write:
        from common import append_results

        (HERE / "results" / "goal_picture_distribution.json").write_text(json.dumps(raw, indent=1) + "\n")
        append_results("Goal pictures: PixelPush with goal pictures from one distribution, before and after", text)


if __name__ == "__main__":
    main()
