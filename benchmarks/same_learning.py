"""Does a change leave learning as it was? The same presets, seeds and budgets on a base commit and on
the working tree, their ``metrics.csv`` compared row by row, and their training speed.

Every learned quantity (success, return, losses, Q) must match (numbers to float32 precision); timing
columns are only reported. The base commit is checked out into a temporary git worktree.

    .venv/bin/python benchmarks/same_learning.py --base 9623a6b [--write]
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from common import append_results

ROOT = Path(__file__).resolve().parent.parent
#: case name -> (preset, its arguments)
CASES = {
    "bitflip-her": ("bitflip-her", ["--n-bits", "8", "--total-steps", "6000", "--eval-interval", "2000"]),
    # 15 actions at batch 256 / (256, 256): the padded head and the wide weight-gradient layout of nets.Linear
    "bitflip-her-15-wide": (
        "bitflip-her",
        [
            "--n-bits",
            "15",
            "--batch-size",
            "256",
            "--hidden-sizes",
            "256",
            "256",
            "--total-steps",
            "3000",
            "--eval-interval",
            "1500",
        ],
    ),
    "pointreach-sac-her": ("pointreach-sac-her", ["--total-steps", "4000", "--eval-interval", "2000"]),
    "pointreach-td3-her": ("pointreach-sac-her", ["--algo", "td3", "--total-steps", "4000", "--eval-interval", "2000"]),
    "pointreach-qtopt-her": ("pointreach-qtopt-her", ["--total-steps", "3000", "--eval-interval", "1500"]),
    "pointreach-mt-ppo-onehot": ("pointreach-mt-ppo-onehot", ["--total-steps", "8192", "--eval-interval", "4096"]),
    "pointreach-mt-sac-onehot": ("pointreach-mt-sac-onehot", ["--total-steps", "3000", "--eval-interval", "1500"]),
    # from pictures: the scene and its goal picture (SAC), QT-Opt's two networks, BC-Z's FiLM encoder
    "pixelreach-sac-her": (
        "pixelreach-sac-her",
        ["--total-steps", "1600", "--learning-starts", "800", "--eval-interval", "800", "--eval-episodes", "20"],
    ),
    "pixelpush-sac-her": (
        "pixelpush-sac-her",
        ["--total-steps", "1600", "--learning-starts", "800", "--eval-interval", "800", "--eval-episodes", "20"],
    ),
    "grasp-qtopt-pixels": (
        "grasp-qtopt-pixels",
        ["--total-steps", "1200", "--learning-starts", "400", "--eval-interval", "600", "--eval-episodes", "20"],
    ),
    "grasp-qtopt-pixels-conv": (
        "grasp-qtopt-pixels",
        [
            "--fusion",
            "conv",
            "--total-steps",
            "1200",
            "--learning-starts",
            "400",
            "--eval-interval",
            "600",
            "--eval-episodes",
            "20",
        ],
    ),
    "bc-tabletop-language": (
        "bc-tabletop-language",
        ["--dataset", "tabletop-demos", "--total-steps", "300", "--eval-interval", "150", "--eval-episodes", "4"],
    ),
}
#: datasets a case reads, collected once (by the working tree) into the cases' folder: name -> ``taskrl demos`` arguments
DATASETS = {"tabletop-demos": ["collect", "tabletop", "--episodes", "10", "--noise", "0.2", "--no-progress"]}
TIMING = {"wall_seconds", "env_steps_per_s", "updates_per_s"}
#: exploration levels logged under another name (the value is the agent's, at the same step)
RENAMED = {"epsilon", "random_action_prob"}


def _same(a: str, b: str) -> bool:
    """Equal values; numbers to float32 precision (success rates became exact fractions of episodes:
    0.9 where float32 gave 0.8999999761581421)."""
    if a == b:
        return True
    try:
        return math.isclose(float(a), float(b), rel_tol=1e-6, abs_tol=1e-7)
    except ValueError:
        return False


def run(src: Path, preset: str, args: list[str], out: Path) -> list[dict[str, str]]:
    env = {**os.environ, "PYTHONPATH": str(src)}
    subprocess.run(
        [sys.executable, "-m", "taskrl.cli", "train", preset, *args, "--out", str(out), "--no-progress", "--no-tensorboard"],
        check=True,
        env=env,
        capture_output=True,
        cwd=out.parent,
    )
    return list(csv.DictReader(open(out / "metrics.csv")))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--base", required=True, help="the commit to compare against")
    parser.add_argument("--presets", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    lines = [
        "| case | rows | learned columns compared | identical | training env steps/s (base -> now) |",
        "|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "base"
        subprocess.run(["git", "worktree", "add", "-q", "--detach", str(tree), args.base], check=True, cwd=ROOT)
        try:
            for name, collect in DATASETS.items():
                if any(name in CASES[case][1] for case in args.presets):
                    command = [sys.executable, "-m", "taskrl.cli", "demos", *collect, "--out", str(Path(tmp) / name)]
                    subprocess.run(command, check=True, env={**os.environ, "PYTHONPATH": str(ROOT / "src")}, capture_output=True)
            for case in args.presets:
                preset, case_args = CASES[case]
                base = run(tree / "src", preset, case_args, Path(tmp) / f"{case}-base")
                now = run(ROOT / "src", preset, case_args, Path(tmp) / f"{case}-now")
                learned = sorted((set(base[0]) & set(now[0])) - TIMING - RENAMED)
                same = len(base) == len(now) and all(_same(a[k], b[k]) for a, b in zip(base, now) for k in learned)
                speed = [float(r[-1]["env_steps"]) / float(r[-1]["wall_seconds"]) for r in (base, now)]
                lines.append(
                    f"| {case} | {len(now)} | {len(learned)} | {'yes' if same else 'NO'} | {speed[0]:,.0f} -> {speed[1]:,.0f} |"
                )
                print(lines[-1], flush=True)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT)
    if args.write:
        append_results(f"Same learning as commit {args.base}", "\n".join(lines))


if __name__ == "__main__":
    main()
