"""Grasp success of uniformly random actions: the floor a learned grasp policy must beat, per object set and hold
tolerance (the fair bin asks a random closing action to hold in 5-10% of attempts).

    .venv/bin/python benchmarks/grasp_random.py --write   # about 10,000 attempts per row, seed 0
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from taskrl.envs.grasp import Grasp, GraspSettings

HERE = Path(__file__).resolve().parent


def random_success(
    objects: str, attempts: int = 10_000, bins: int = 1024, seed: int = 0, tolerance: float = GraspSettings.tolerance
) -> tuple[int, float]:
    """(attempts ended, fraction that held an object) for actions uniform in the box; ``tolerance``: the env's."""
    env = Grasp(GraspSettings(objects=objects, tolerance=tolerance), num_envs=bins, seed=seed)
    env.reset(seed=seed)
    generator = torch.Generator().manual_seed(seed)
    ended = held = 0
    while ended < attempts:
        _, _, terminated, truncated, info = env.step(torch.rand(bins, 4, generator=generator) * 2 - 1)
        done = terminated | truncated
        ended += int(done.sum())
        held += int((info["is_success"] & done).sum())
    return ended, held / ended


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tolerances", type=float, nargs="+", default=[0.025, 0.04, 0.05, GraspSettings.tolerance])
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = []
    for tolerance in args.tolerances:
        for objects in ("train", "held_out"):
            ended, success = random_success(objects, tolerance=tolerance)
            rows.append({"tolerance": tolerance, "objects": objects, "attempts": ended, "success": success})
            print(rows[-1], flush=True)
    lines = ["| tolerance (pixels at 64x64) | training objects | held-out objects |", "|---|---|---|"]
    for tolerance in args.tolerances:
        mine = {r["objects"]: r["success"] for r in rows if r["tolerance"] == tolerance}
        default = " (the default)" if tolerance == GraspSettings.tolerance else ""
        lines.append(f"| {tolerance}{default} ({tolerance * 64:.1f}) | {mine['train']:.3f} | {mine['held_out']:.3f} |")
    text = "\n".join(lines)
    print(text)
    if args.write:
        from common import append_results

        (HERE / "results" / "grasp_random.json").write_text(json.dumps(rows, indent=1) + "\n")
        append_results(
            "Grasp env: random actions' success by hold tolerance",
            "Actions uniform in the box on 1,024 bins until about 10,000 attempts ended (seed 0), the bin's default "
            "sizes (squares of half-side 0.052-0.065 and ellipses of half-length 0.075-0.10 against the 0.14 opening: "
            "yaw matters for every square and elongated object) and move (0.1 of the bin per step); share of attempts "
            "that held. Raw data: `benchmarks/results/grasp_random.json`.\n\n" + text,
        )


if __name__ == "__main__":
    main()
