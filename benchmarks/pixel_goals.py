"""Goals as pictures against goals as states: SAC + HER from pictures and from positions, the price of pixels.

Two tasks (``--task``): ``reach`` (PixelReach against PointReach: the agent itself moves to the goal) and
``push`` (PixelPush from pictures against PixelPush from positions: a block pushed to a goal). For every seed:
``taskrl train PICTURES_PRESET --seed S --stop-at-success 0.9`` (the scene and the goal as 32x32 pictures) and
``taskrl train STATES_PRESET --seed S --stop-at-success 0.9`` (the same task from positions), each its own
process with one torch thread. A run directory that already holds a finished run is
read instead of trained again, so runs made by hand with these commands (or a stopped benchmark) count.
Extra arms (``--arm NAME=FLAGS``, e.g. ``--arm "shift 4=--shift 4"``) run the pixel preset with other
flags. Raw per-evaluation curves: ``benchmarks/results/pixel_goals.json``; a RESULTS section.

    .venv/bin/python benchmarks/pixel_goals.py --seeds 0 1 2 --out /work/runs-bench/pixel-goals
    .venv/bin/python benchmarks/pixel_goals.py --task push --seeds 0 1 2 --out /work/runs-bench/pixel-push
"""

from __future__ import annotations

import argparse
import csv
import json
import shlex
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import append_results  # noqa: E402

TASKRL = str(Path(sys.executable).with_name("taskrl"))
TARGET = 0.9
#: task -> input -> preset
TASKS = {
    "reach": {"pictures": "pixelreach-sac-her", "states": "pointreach-sac-her"},
    "push": {"pictures": "pixelpush-sac-her", "states": "pixelpush-state-sac-her"},
}
#: task -> (RESULTS title, raw data file, what the presets set)
REPORTS = {
    "reach": (
        "Goal pictures: SAC + HER on PixelReach from pictures against states",
        "pixel_goals.json",
        "16 copies, 0.25 updates per env step, batch 256, (64, 64) networks, gamma 0.95; budgets: pictures 100,000 "
        "env steps, states 40,000",
    ),
    "push": (
        "Goal pictures: SAC + HER on PixelPush (a block to push) from pictures against states",
        "pixel_goals_push.json",
        "16 copies, 0.25 updates per env step, batch 256, (256, 256) networks, gamma 0.95; from pictures the pusher's "
        "position beside them, from states the pusher's and the block's; budgets 300,000 env steps",
    ),
}


def train(preset: str, seed: int, run_dir: Path, flags: list[str], max_hours: float) -> list[dict]:
    """The run's evaluations (trained now unless ``run_dir`` holds a finished run)."""
    if not (run_dir / "learning_curve.png").exists():  # written when a run ends (run.json: when it starts)
        command = [TASKRL, "train", preset, "--seed", str(seed), "--stop-at-success", str(TARGET), "--threads", "1"]
        command += ["--max-hours", str(max_hours), "--out", str(run_dir), "--no-progress", *flags]
        subprocess.run(command, check=True, capture_output=True)
    with open(run_dir / "metrics.csv") as f:
        rows = list(csv.DictReader(f))
    keep = ("env_steps", "updates", "wall_seconds", "success_rate")
    return [{k: float(r[k]) for k in keep} for r in rows if r.get("success_rate") not in (None, "")]


def first_at_target(curve: list[dict]) -> dict | None:
    return next((row for row in curve if row["success_rate"] >= TARGET), None)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--task", choices=sorted(TASKS), default="reach")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--out", default="runs/bench-pixel-goals")
    parser.add_argument("--max-hours", type=float, default=1.0, help="per run (the issue's budget: 1 hour)")
    parser.add_argument("--arm", action="append", default=[], help="NAME=FLAGS: the pixel preset with other flags")
    parser.add_argument("--arm-seeds", nargs="+", type=int, default=[0], help="seeds of the extra arms")
    args = parser.parse_args()
    inputs = TASKS[args.task]
    arms = [("pictures", inputs["pictures"], [], args.seeds), ("states", inputs["states"], [], args.seeds)]
    for spec in args.arm:
        name, _, flags = spec.partition("=")
        arms.append((f"pictures, {name}", inputs["pictures"], shlex.split(flags), args.arm_seeds))
    results = []
    raw = Path("benchmarks/results") / REPORTS[args.task][1]
    for name, preset, flags, seeds in arms:
        for seed in seeds:
            slug = name.replace(", ", "-").replace(" ", "")
            curve = train(preset, seed, Path(args.out) / f"{slug}-seed{seed}", flags, args.max_hours)
            results.append({"arm": name, "preset": preset, "flags": flags, "seed": seed, "curve": curve})
            raw.parent.mkdir(exist_ok=True)
            raw.write_text(json.dumps(results, indent=2) + "\n")
            print(name, seed, first_at_target(curve) or curve[-1], flush=True)
    report(results, args)


def report(results: list[dict], args) -> None:
    title, raw, settings = REPORTS[args.task]
    interval = {"reach": "3,000", "push": "10,000"}[args.task]
    lines = [
        "Each run its own process with one torch thread, the other core busy with other benchmarks; each preset's own "
        f"settings ({settings}; from pictures the DrQ encoder reads the 32x32 scene and goal pictures stacked, random "
        "shifts of up to 2 pixels, one offset per state; pictures centred before the encoder); stopped at the first "
        f"evaluation at or above {TARGET} (100 episodes every {interval} env steps), at the preset's budget or after "
        f"{args.max_hours} h. Raw curves: `benchmarks/results/{raw}`.",
        "",
        f"| input | seed | env steps to {TARGET} | updates | training s | last success | updates/s |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        hit, last = first_at_target(r["curve"]), r["curve"][-1]
        row = hit or last
        rate = row["updates"] / max(row["wall_seconds"], 1e-9)
        reached = f"{row['env_steps']:,.0f}" if hit else f"not reached ({last['env_steps']:,.0f} run)"
        lines.append(
            f"| {r['arm']}{' `' + ' '.join(r['flags']) + '`' if r['flags'] else ''} | {r['seed']} | {reached} | "
            f"{row['updates']:,.0f} | {row['wall_seconds']:.0f} | {last['success_rate']:.2f} | {rate:.1f} |"
        )
    price = []
    for seed in sorted({r["seed"] for r in results}):
        pair = {r["arm"]: first_at_target(r["curve"]) for r in results if r["seed"] == seed and r["arm"] in TASKS[args.task]}
        if pair.get("pictures") and pair.get("states"):
            price.append(
                (
                    pair["pictures"]["env_steps"] / pair["states"]["env_steps"],
                    pair["pictures"]["wall_seconds"] / pair["states"]["wall_seconds"],
                )
            )
    if price:
        lines += [
            "",
            f"Price of pixels (pictures / states, per seed where both reached {TARGET}): env steps "
            + ", ".join(f"{p[0]:.1f}x" for p in price)
            + f" (median {statistics.median(p[0] for p in price):.1f}x); training time "
            + ", ".join(f"{p[1]:.0f}x" for p in price)
            + f" (median {statistics.median(p[1] for p in price):.0f}x).",
        ]
    append_results(title, "\n".join(lines))


if __name__ == "__main__":
    main()
