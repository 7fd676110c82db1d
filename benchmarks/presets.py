"""Run named presets over seeds and record their final success, env steps and training time.

.venv/bin/python benchmarks/presets.py pointreach-sac-her pointreach-qtopt-her --seeds 0 1 2 --write
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
from pathlib import Path

import torch

import taskrl
from common import append_results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("presets", nargs="+")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--stop-at-success", type=float, default=0.0, help="0 = train each preset's full budget")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    lines = ["| preset | seed | final success | env steps | training seconds | updates/s |", "|---|---|---|---|---|---|"]
    summary = []
    for preset in args.presets:
        finals = []
        for seed in args.seeds:
            with tempfile.TemporaryDirectory() as tmp:
                m = taskrl.train(
                    preset,
                    out=Path(tmp) / "run",
                    seed=seed,
                    threads=args.threads,
                    tensorboard=False,
                    save_replay=False,
                    stop_at_success=args.stop_at_success,
                ).metrics
            finals.append(m["success_rate"])
            print(json.dumps({"preset": preset, "seed": seed, **m}), flush=True)
            lines.append(
                f"| {preset} | {seed} | {m['success_rate']:.2f} | {m['env_steps']:,} | {m['wall_seconds']:.1f} | "
                f"{m['updates'] / max(m['wall_seconds'], 1e-9):.0f} |"
            )
        summary.append(f"- `{preset}`: median final success {statistics.median(finals):.2f} over seeds {args.seeds}")
    text = "\n".join(lines + [""] + summary)
    print(text)
    if args.write:
        stop = f", stopping at {args.stop_at_success:.0%} success" if args.stop_at_success else ""
        append_results(
            f"Presets: {', '.join(args.presets)}",
            f"Each preset's own budget and settings{stop}; torch threads {args.threads}; "
            "greedy evaluation on 100 fixed episodes; training seconds exclude evaluation.\n\n" + text,
        )


if __name__ == "__main__":
    main()
