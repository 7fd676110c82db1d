"""FetchPush-v4 side by side: SAC + hindsight relabelling against QT-Opt + hindsight relabelling.

Both methods train on FetchPush-v4 with their presets (``fetchpush-sac-her``, ``fetchpush-qtopt-her``:
8 copies, relabelling ``future`` with k = 4, 100 evaluation episodes every 25k env steps) on the same
env-step ``--budget`` (the hindsight paper's 2M by default), one run per core. A run directory that
already holds checkpoints is resumed, so the comparison can be built over several sittings
(``--hours`` stops every run after that much time in this sitting; the runs checkpoint every 100k
env steps and on stopping). ``--report`` trains nothing and reports the runs as they stand, which
also works while they are still training.

Written: per run, the env steps and training time at which evaluation success first reached 90%,
the best and last success, throughput, and the learning curves against env steps and against
training hours (``benchmarks/figures/fetchpush_sac_qtopt.png``).

    .venv/bin/python benchmarks/fetchpush_compare.py --seeds 0 --workers 2 --write
"""

from __future__ import annotations

import argparse
import json
import statistics
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

METHODS = ("fetchpush-sac-her", "fetchpush-qtopt-her")
HERE = Path(__file__).resolve().parent
OUT = HERE / "out" / "fetchpush"
TARGET = 0.9


def run_one(preset: str, seed: int, budget: int, hours: float, root: Path = OUT) -> str:
    import torch

    import taskrl

    torch.set_num_threads(1)
    out = root / f"{preset}-s{seed}"
    overrides = dict(total_steps=budget, tensorboard=False)
    if hours:
        overrides["max_hours"] = hours
    if (out / "checkpoints").exists():
        taskrl.train(resume=out, **overrides)
    else:
        taskrl.train(preset, out=out, seed=seed, **overrides)
    return str(out)


def summarise(run_dir: Path) -> dict:
    from taskrl.config import load
    from taskrl.logger import read_metrics

    config = load(run_dir / "config.json")  # also reads runs saved before the registries
    rows = [r for r in read_metrics(run_dir / "metrics.csv") if r["success_rate"] is not None]
    reached = next((r for r in rows if r["success_rate"] >= TARGET), None)
    learning = [r for r in rows if r["updates_per_s"]]
    last = rows[-1]
    section = config.algo_settings
    if config.algo == "sac":
        exploration = "policy entropy"
    else:
        start, end = section.random_action_prob, section.random_action_prob_end
        exploration = f"{start}{f'->{end}' if end != start else ''} random, noise {section.noise_std}"
    return {
        "run": run_dir.name,
        "algo": config.algo,
        "seed": config.seed,
        "hidden": list(section.hidden_sizes),
        "updates_per_step": config.updates_per_step,
        "exploration": exploration,
        "env_steps": last["env_steps"],
        "updates": last["updates"],
        "hours": last["wall_seconds"] / 3600,
        "last_success": last["success_rate"],
        "best_success": max(r["success_rate"] for r in rows),
        "steps_to_target": reached["env_steps"] if reached else None,
        "hours_to_target": reached["wall_seconds"] / 3600 if reached else None,
        "env_steps_per_s": last["env_steps"] / max(last["wall_seconds"], 1e-9),
        "updates_per_s": statistics.median(r["updates_per_s"] for r in learning) if learning else 0.0,
        "curve": [(r["env_steps"], r["wall_seconds"] / 3600, r["success_rate"]) for r in rows],
    }


def curves_png(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (by_steps, by_hours) = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for r in results:
        steps, hours, success = zip(*r["curve"])
        label = f"{r['run']}: {r['algo']} + HER, {r['updates_per_step']} updates/step"
        by_steps.plot([s / 1e6 for s in steps], success, marker=".", label=label)
        by_hours.plot(hours, success, marker=".", label=label)
    for ax, xlabel in ((by_steps, "env steps (millions)"), (by_hours, "training hours (one CPU core)")):
        ax.axhline(TARGET, color="grey", linestyle="--", linewidth=0.8)
        ax.set_xlabel(xlabel)
        ax.grid(alpha=0.3)
    by_steps.set_ylabel("evaluation success (100 episodes)")
    by_steps.set_ylim(0, 1)
    by_steps.legend(fontsize=8)
    fig.suptitle("FetchPush-v4")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def table(results: list[dict]) -> str:
    lines = [
        "| run | network | exploration | updates / env step | env steps | training hours | env steps/s | updates/s | "
        "best success | last success | env steps to 90% | hours to 90% |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        to_steps = f"{r['steps_to_target']:,}" if r["steps_to_target"] else "not reached"
        to_hours = f"{r['hours_to_target']:.2f}" if r["hours_to_target"] else "-"
        lines.append(
            f"| {r['run']} | {tuple(r['hidden'] or ())} | {r['exploration']} | {r['updates_per_step']} | {r['env_steps']:,} | "
            f"{r['hours']:.2f} | {r['env_steps_per_s']:.0f} | {r['updates_per_s']:.1f} | {r['best_success']:.2f} | "
            f"{r['last_success']:.2f} | {to_steps} | {to_hours} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--budget", type=int, default=2_000_000, help="env steps per run")
    parser.add_argument(
        "--hours", type=float, default=0.0, help="stop each run after this many hours here (0: run to the budget)"
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--report", action="store_true", help="train nothing; report the runs as they stand")
    parser.add_argument("--out", type=Path, default=OUT, help="run directories <preset>-s<seed> (resumed when present)")
    parser.add_argument(
        "--extra",
        type=Path,
        nargs="*",
        default=[],
        help="more run directories to report beside them (e.g. a variant trained with other settings)",
    )
    parser.add_argument("--figure", type=Path, default=HERE / "figures" / "fetchpush_sac_qtopt.png")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    args.figure.parent.mkdir(parents=True, exist_ok=True)
    jobs = [(p, s) for s in args.seeds for p in args.methods]
    if not args.report:
        with ProcessPoolExecutor(args.workers) as pool:
            list(pool.map(run_one, *zip(*jobs), [args.budget] * len(jobs), [args.hours] * len(jobs), [args.out] * len(jobs)))
    run_dirs = [args.out / f"{p}-s{s}" for p, s in jobs] + list(args.extra)
    results = [summarise(d) for d in run_dirs if (d / "metrics.csv").exists()]
    (args.out / "results.json").write_text(json.dumps(results, indent=2))
    curves_png(results, args.figure)
    text = table(results)
    print(text)
    if args.write:
        from common import append_results

        append_results(
            "FetchPush-v4: SAC + HER and QT-Opt + HER side by side",
            f"Budget {args.budget:,} env steps per run, seeds {args.seeds}, one run per core (one torch thread each); "
            f"evaluation: 100 episodes every 25k env steps, success at the final step. "
            f"Curves: `benchmarks/figures/{args.figure.name}`.\n\n{text}",
        )


if __name__ == "__main__":
    main()
