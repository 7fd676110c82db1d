"""Did keeping pictures as pictures move the grasp probe? ``grasp_probe.py`` (the critic's network taught whether
closing where the gripper is would hold an object) on a base commit, where pictures were flattened into the float
input, and on the working tree, seed for seed, beside the working tree on other seeds (the probe's own noise).

    .venv/bin/python benchmarks/picture_input_probe.py --base 6d61b9d [--write]
"""

from __future__ import annotations

import argparse
import ast
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from common import append_results

ROOT = Path(__file__).resolve().parent.parent
RAW = ROOT / "benchmarks" / "results" / "picture_input_probe.json"


def curve(src: Path, seed: int, updates: int, states: int) -> list[dict]:
    """The probe's held-out AUC every 1,000 updates, from the code under ``src`` (its printed lines)."""
    with tempfile.TemporaryDirectory() as tmp:
        bench = Path(tmp) / "benchmarks"
        subprocess.run(["cp", "-r", str(src.parent / "benchmarks"), str(bench)], check=True)
        command = [sys.executable, "grasp_probe.py", "--updates", str(updates), "--train-states", str(states)]
        command += ["--arms", "orthogonal:4", "--seed", str(seed)]
        env = {**os.environ, "PYTHONPATH": str(src)}
        done = subprocess.run(command, cwd=bench, env=env, check=True, capture_output=True, text=True)
    return [ast.literal_eval(line.split(" ", 3)[3]) for line in done.stdout.splitlines() if "'auc'" in line]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--base", required=True, help="the commit where pictures were flattened into the float input")
    parser.add_argument("--updates", type=int, default=2000)
    parser.add_argument("--train-states", type=int, default=8000)
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "base"
        subprocess.run(["git", "worktree", "add", "-q", "--detach", str(tree), args.base], check=True, cwd=ROOT)
        try:
            runs = {"base, seed 0": curve(tree / "src", 0, args.updates, args.train_states)}
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT)
    for seed in (0, 1, 2):
        runs[f"now, seed {seed}"] = curve(ROOT / "src", seed, args.updates, args.train_states)
    RAW.write_text(json.dumps({"base": args.base, "runs": runs}, indent=2) + "\n")
    steps = [point["updates"] for point in runs["base, seed 0"]]
    lines = ["| code | " + " | ".join(f"AUC at {s:,} updates" for s in steps) + " |", "|---" * (len(steps) + 1) + "|"]
    for name, points in runs.items():
        lines.append(f"| {name} | " + " | ".join(f"{p['auc']:.3f}" for p in points) + " |")
    table = "\n".join(lines)
    print(table)
    if args.write:
        body = (
            f"The grasp probe (`grasp_probe.py --arms orthogonal:4`, {args.train_states:,} training states, held-out AUC) "
            f"at commit {args.base}, where a picture travelled as the trailing float columns of the flat input, and on "
            "the working tree, where it reaches the encoder as the stored uint8 picture; seeds 1 and 2 of the working "
            f"tree give the probe's own spread. Raw data: `results/{RAW.name}`.\n\n{table}"
        )
        append_results("Pictures kept as pictures: the grasp probe before and after", body)


if __name__ == "__main__":
    main()
