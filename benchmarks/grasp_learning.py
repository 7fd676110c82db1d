"""QT-Opt grasping from the camera: the preset against the preset with scripted exploration, per-evaluation curves.

Each arm is ``taskrl train grasp-qtopt-pixels --seed S --threads 1 --max-hours H`` plus its flags, its own
process; a run directory that already holds a finished run (its ``learning_curve.png``) is read instead of trained again, so
runs made by hand with these commands count. Evaluation is the greedy policy alone (100 attempts on the training
objects); ``train success`` counts every training attempt, scripted ones included.

    .venv/bin/python benchmarks/grasp_learning.py --seeds 0 --max-hours 0.75 --out /work/runs-bench/grasp --write
"""

from __future__ import annotations

import argparse
import csv
import json
import shlex
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import append_results  # noqa: E402

TASKRL = str(Path(sys.executable).with_name("taskrl"))
PRESET = "grasp-qtopt-pixels"
ARMS = {
    "preset": "",
    "scripted exploration": "--scripted-exploration 0.5 --scripted-steps 60000",
}
RANDOM_SUCCESS = 0.014  # benchmarks/grasp_random.py, training objects


def run(flags: str, seed: int, run_dir: Path, max_hours: float) -> list[dict]:
    if not (run_dir / "learning_curve.png").exists():  # written when a run ends (run.json: when it starts)
        command = [TASKRL, "train", PRESET, "--seed", str(seed), "--threads", "1", "--max-hours", str(max_hours)]
        command += ["--out", str(run_dir), "--no-progress", *shlex.split(flags)]
        subprocess.run(command, check=True, capture_output=True)
    with open(run_dir / "metrics.csv") as f:
        rows = [r for r in csv.DictReader(f) if r.get("success_rate") not in (None, "")]
    keep = ("env_steps", "updates", "wall_seconds", "success_rate", "train_success")
    return [{k: float(r[k]) for k in keep} for r in rows]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--arms", nargs="+", default=list(ARMS), choices=list(ARMS))
    parser.add_argument("--max-hours", type=float, default=1.3)
    parser.add_argument("--out", default="runs/bench-grasp")
    parser.add_argument("--write", action="store_true", help="replace the RESULTS section")
    args = parser.parse_args()
    results = []
    for arm in args.arms:
        for seed in args.seeds:
            slug = arm.replace(" ", "-")
            curve = run(ARMS[arm], seed, Path(args.out) / f"{slug}-seed{seed}", args.max_hours)
            results.append({"arm": arm, "flags": ARMS[arm], "seed": seed, "curve": curve})
            print(arm, seed, curve[-1], flush=True)
    raw = Path(__file__).parent / "results" / "grasp_learning.json"
    raw.write_text(json.dumps(results, indent=2) + "\n")
    if args.write:
        report(results, args)


def report(results: list[dict], args) -> None:
    lines = [
        f"`taskrl train {PRESET} --seed S --threads 1 --max-hours {args.max_hours}` plus each arm's flags, one process "
        "each, the other core busy with other benchmarks; greedy evaluation on 100 attempts at the training objects "
        f"every 5,000 env steps (uniformly random actions: {RANDOM_SUCCESS}); `train success` counts every training "
        "attempt, scripted ones included. Raw curves: `benchmarks/results/grasp_learning.json`.",
        "",
        "| arm | seed | env steps | updates | wall s | best greedy success (at env steps) | last greedy success | last train success |",
        "|---|---|---:|---:|---:|---|---:|---:|",
    ]
    for r in results:
        last = r["curve"][-1]
        best = max(r["curve"], key=lambda row: row["success_rate"])
        flags = f" `{r['flags']}`" if r["flags"] else ""
        lines.append(
            f"| {r['arm']}{flags} | {r['seed']} | {last['env_steps']:,.0f} | {last['updates']:,.0f} | "
            f"{last['wall_seconds']:.0f} | {best['success_rate']:.2f} ({best['env_steps']:,.0f}) | "
            f"{last['success_rate']:.2f} | {last['train_success']:.3f} |"
        )
    lines += ["", "Every evaluation (env steps: greedy success):", ""]
    for r in results:
        points = ", ".join(f"{row['env_steps'] / 1e3:.0f}k: {row['success_rate']:.2f}" for row in r["curve"][1:])
        lines.append(f"- {r['arm']}, seed {r['seed']}: {points}")
    append_results("Grasp from pixels: scripted exploration against the preset, equal budgets", "\n".join(lines))


if __name__ == "__main__":
    main()
