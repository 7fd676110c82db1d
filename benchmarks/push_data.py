"""What a pushing run's own data shows: how often the block moved in the episodes it collected, over the run.

A run that never moves the block gives hindsight only goals where the block already is, on which every action is
equally good; so where QT-Opt's Q stays flat over actions on FetchPush (RESULTS, "QT-Opt + HER learning to push
(fetchpush)"), this counts, from each run's saved replay (every episode kept), the share of episodes in which the block
ended at least 1 cm and at least 5 cm (the success radius) from where it started, per slice of env steps.

    .venv/bin/python benchmarks/push_data.py --runs QT-Opt=RUN_DIR SAC=RUN_DIR [--slice 50000] [--write]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"


def block_moves(run_dir: Path, slice_steps: int) -> list[dict]:
    """Per slice of ``slice_steps`` env steps (episodes in the order they were stored): episodes, and the shares whose
    block (``achieved_goal``) ended >= 1 cm and >= 5 cm from its start."""
    from taskrl.checkpoint import load_checkpoint
    from taskrl.replay.storage import ring_rows

    saved = load_checkpoint(run_dir / "checkpoints", ("replay",))["replay"]
    _, tail, count, *_ = (int(x) for x in saved["rings"])
    slots = saved["length"].shape[0]
    ids = (torch.arange(count) + tail) % slots
    lengths = saved["length"][ids]
    goals = saved["obs/achieved_goal"]
    first = saved["episode_obs_start"][ids]
    last = ring_rows(first, lengths + 1, goals.shape[0])[torch.cumsum(lengths + 1, 0) - 1]  # each episode's final obs
    moved = (goals[last] - goals[first]).norm(dim=1)
    ends = torch.cumsum(lengths, 0)  # env steps collected when each episode was stored
    rows = []
    for start in range(0, int(ends[-1]), slice_steps):
        inside = (ends > start) & (ends <= start + slice_steps)
        n = int(inside.sum())
        if n:
            rows.append(
                {
                    "env_steps": start + slice_steps,
                    "episodes": n,
                    "moved_1cm": float((moved[inside] >= 0.01).float().mean()),
                    "moved_5cm": float((moved[inside] >= 0.05).float().mean()),
                }
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", nargs="+", required=True, help="LABEL=RUN_DIR, each a run with its replay saved")
    parser.add_argument("--slice", type=int, default=50_000, help="env steps per row")
    parser.add_argument("--note", default="", help="a note for the written section (where the runs came from)")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    found = {}
    for spec in args.runs:
        label, _, path = spec.partition("=")
        found[label] = {"run": path, "rows": block_moves(Path(path), args.slice)}
        print(label, json.dumps(found[label]["rows"]), flush=True)
    marks = sorted({r["env_steps"] for f in found.values() for r in f["rows"]})
    by = {label: {r["env_steps"]: r for r in f["rows"]} for label, f in found.items()}
    header = "| env steps | " + " | ".join(f"{label}: moved >= 1 cm / >= 5 cm" for label in found) + " |"
    lines = [header, "|---|" + "---|" * len(found)]
    for mark in marks:
        cells = [
            f"{by[label][mark]['moved_1cm']:.2f} / {by[label][mark]['moved_5cm']:.2f}" if mark in by[label] else "-"
            for label in found
        ]
        lines.append(f"| {mark:,} | " + " | ".join(cells) + " |")
    text = "\n".join(lines)
    print(text)
    if args.write:
        from common import append_results

        (RESULTS / "push_data.json").write_text(json.dumps(found, indent=1) + "\n")
        append_results(
            "FetchPush: how often each learner's own episodes moved the block",
            f"From each run's saved replay (every episode kept), the share of the episodes stored in each slice of "
            f"{args.slice:,} env steps whose block ended at least 1 cm / at least 5 cm (the success radius) from where "
            f"it started. {args.note} Raw data: `benchmarks/results/push_data.json`.\n\n" + text,
        )


if __name__ == "__main__":
    main()
