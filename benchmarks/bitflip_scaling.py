"""The hindsight paper's bit-flipping contrast: DQN + relabelling against plain DQN as n grows.

Each configuration runs as its own ``taskrl train`` process (so its peak memory is its own),
stops at 90% greedy evaluation success or at the budget, and reports env steps, training
wall-clock and peak RSS. Plain DQN gets the same budget as DQN + HER for the same n.

    .venv/bin/python benchmarks/bitflip_scaling.py --write
    .venv/bin/python benchmarks/bitflip_scaling.py --her-bits 50 --plain-bits --write   # one case
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

# The child reports its own peak resident memory when it exits.
CHILD = (
    "import json, resource, sys; from taskrl.cli import main; code = main(sys.argv[1:]); "
    "print(json.dumps({'peak_rss_kib': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}), file=sys.stderr); "
    "sys.exit(code)"
)
BUDGETS = {10: 50_000, 13: 100_000, 15: 100_000, 20: 150_000, 30: 300_000, 40: 600_000, 50: 2_000_000}


def run(n_bits: int, her: str, budget: int, seed: int, threads: int, extra: list[str]) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [
            sys.executable,
            "-c",
            CHILD,
            "train",
            "bitflip-her",
            "--out",
            f"{tmp}/run",
            "--no-progress",
            "--no-tensorboard",
            "--n-bits",
            str(n_bits),
            "--her",
            her,
            "--total-steps",
            str(budget),
            "--seed",
            str(seed),
            "--stop-at-success",
            "0.9",
            "--eval-interval",
            str(max(1_000, budget // 100)),
            "--threads",
            str(threads),
            "--no-save-replay",
            "--checkpoint-interval",
            str(10**12),
            *extra,
        ]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        out, err = proc.stdout, proc.stderr
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed:\n{err}")
        metrics = json.loads(out.strip().splitlines()[-1])
        metrics["peak_rss_mib"] = json.loads(err.strip().splitlines()[-1])["peak_rss_kib"] / 1024
    return metrics


def run_measured(n_bits: int, her: str, budget: int, seed: int, threads: int, extra: list[str]) -> dict:
    metrics = run(n_bits, her, budget, seed, threads, extra)
    return {
        "n_bits": n_bits,
        "her": her,
        "seed": seed,
        "budget": budget,
        "solved": metrics["success_rate"] >= 0.9,
        "success_rate": metrics["success_rate"],
        "env_steps": metrics["env_steps"],
        "wall_seconds": metrics["wall_seconds"],
        "updates": metrics["updates"],
        "peak_rss_mib": metrics["peak_rss_mib"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--her-bits", type=int, nargs="*", default=[10, 20, 30, 40, 50])
    parser.add_argument("--plain-bits", type=int, nargs="*", default=[10, 13, 15, 20])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--write", action="store_true", help="append the table to benchmarks/RESULTS.md")
    parser.add_argument("extra", nargs="*", help="extra flags for taskrl train (after --)")
    args = parser.parse_args()

    rows = []
    for n in sorted(args.her_bits, reverse=True):
        rows.append(run_measured(n, "future", BUDGETS.get(n, 100_000 * n), args.seed, args.threads, args.extra))
        print(json.dumps(rows[-1]), flush=True)
    for n in sorted(args.plain_bits, reverse=True):
        rows.append(run_measured(n, "none", BUDGETS.get(n, 100_000 * n), args.seed, args.threads, args.extra))
        print(json.dumps(rows[-1]), flush=True)

    lines = [
        "| n bits | method | budget (env steps) | solved (>= 90%) | final success | env steps | training seconds | peak RSS (MiB) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(rows, key=lambda r: (r["her"] == "none", r["n_bits"])):
        method = "DQN + HER (future, k=4)" if r["her"] != "none" else "plain DQN"
        rss = f"{r['peak_rss_mib']:.0f}"
        lines.append(
            f"| {r['n_bits']} | {method} | {r['budget']:,} | {'yes' if r['solved'] else 'no'} | "
            f"{r['success_rate']:.2f} | {r['env_steps']:,} | {r['wall_seconds']:.1f} | {rss} |"
        )
    table = "\n".join(lines)
    print(table)
    if args.write:
        sys.path.insert(0, str(Path(__file__).parent))
        from common import append_results

        # a plain-DQN-only run answers its own question: it must not replace the HER-against-plain section
        title = (
            "Bit flipping with random goals: DQN + HER against plain DQN"
            if args.her_bits
            else "Plain DQN (no relabelling) on small bit strings: the baseline learns where the paper says it can"
        )
        append_results(
            title,
            f"Preset `bitflip-her` (plain DQN: `--her none`), seed {args.seed}, torch threads {args.threads}; "
            "a run stops at 90% greedy success on 100 fixed evaluation episodes or at its budget. "
            "Training seconds exclude evaluation.\n\n" + table,
        )


if __name__ == "__main__":
    main()
