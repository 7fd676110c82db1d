"""QT-Opt + HER on FetchPush-v4: one change at a time from the preset as it was, to a fixed env-step budget.

Each arm is ``fetchpush-qtopt-her`` with the settings below (``before`` is the preset as it stood before
bounded Q: unbounded Huber targets, lagged twin targets, clipped CEM samples, QT-Opt's 0.3 -> 0.1 random
actions); every other arm changes one thing from ``before``, and ``combined`` makes all the cheap changes at
once. ``sac-network`` gives QT-Opt SAC's preset network (3 x 256) and update ratio (0.25); its CEM targets
cost about 20x more per update on CPU, so it is listed but left out of the default arms, as is ``bounded-sac-network``
(today's preset, bounded Q included, with SAC's network and ratio). ``sac-qtopt-network`` is
the control from the other side: SAC (``fetchpush-sac-her``) given QT-Opt's network (128 x 128) and update ratio
(0.1), which says whether those two settings alone keep an algorithm from learning FetchPush.

Runs resume when their directory holds checkpoints (``--hours`` stops each after that long in this
sitting); ``--report`` trains nothing and reports the runs as they stand, curves in one figure.

    .venv/bin/python benchmarks/qtopt_ablation.py --budget 300000 --workers 2 --write
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from fetchpush_compare import TARGET, summarise

HERE = Path(__file__).resolve().parent
OUT = HERE / "out" / "qtopt_ablation"
PRESET = "fetchpush-qtopt-her"
BEFORE = {"clip_target": False, "twin": "lagged", "truncate": False}
HER_EXPLORATION = {"noise_std": 0.2, "random_action_prob": 0.3, "random_action_prob_end": 0.3}
ARMS: dict[str, tuple[str, dict]] = {
    "before": ("the preset before this change: unbounded Huber targets", BEFORE),
    "clip-target": ("targets clipped to [-1/(1-gamma), 0]", {**BEFORE, "clip_target": True}),
    "independent-twins": ("two online Q-networks, each with its Polyak target", {**BEFORE, "twin": "independent"}),
    "truncated-cem": ("CEM samples from the normal truncated to the box", {**BEFORE, "truncate": True}),
    "her-exploration": ("the hindsight paper's exploration: noise 0.2, random actions 0.3", {**BEFORE, **HER_EXPLORATION}),
    "combined": (
        "all four changes above",
        {"clip_target": True, "twin": "independent", "truncate": True, **HER_EXPLORATION},
    ),
    "sac-network": (
        "SAC's preset network (256, 256, 256) and 0.25 updates per env step",
        {
            **BEFORE,
            "hidden_sizes": (256, 256, 256),
            "updates_per_step": 0.25,
        },
    ),
    "bounded-sac-network": (
        "today's preset (targets clipped) with SAC's network (256, 256, 256) and 0.25 updates per env step",
        {**BEFORE, "clip_target": True, "hidden_sizes": (256, 256, 256), "updates_per_step": 0.25},
    ),
    "bounded-mse": (
        "today's preset (targets clipped) with the squared loss SAC's critics use instead of Huber",
        {**BEFORE, "clip_target": True, "loss": "mse"},
    ),
    "sac-qtopt-network": (
        "not QT-Opt: SAC + HER (`fetchpush-sac-her`) with QT-Opt's network (128, 128) and 0.1 updates per env step",
        {"preset": "fetchpush-sac-her", "hidden_sizes": (128, 128), "updates_per_step": 0.1},
    ),
}
DEFAULT_ARMS = ("combined", "clip-target", "independent-twins", "her-exploration", "truncated-cem", "before")


def run_arm(arm: str, seed: int, budget: int, hours: float, root: Path) -> str:
    import torch

    import taskrl

    torch.set_num_threads(1)
    out = root / f"{arm}-s{seed}"
    overrides = dict(total_steps=budget, tensorboard=False, checkpoint_interval=50_000)
    if hours:
        overrides["max_hours"] = hours
    if (out / "checkpoints").exists():
        taskrl.train(resume=out, **overrides)
    else:
        settings = dict(ARMS[arm][1])
        taskrl.train(settings.pop("preset", PRESET), out=out, seed=seed, **settings, **overrides)
    return str(out)


def curves_png(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for r in results:
        steps, _, success = zip(*r["curve"])
        ax.plot([s / 1e3 for s in steps], success, marker=".", label=r["run"])
    ax.axhline(TARGET, color="grey", linestyle="--", linewidth=0.8)
    ax.set_xlabel("env steps (thousands)")
    ax.set_ylabel("evaluation success (100 episodes)")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("QT-Opt + HER on FetchPush-v4: one change at a time")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def table(results: list[dict], arms: list[str]) -> str:
    lines = [
        "| arm | what changes from `before` | env steps | hours | updates/s | success at 100k / 200k / 300k | best | "
        "env steps to 90% |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for arm, r in zip(arms, results):
        at = {s: success for s, _, success in r["curve"]}
        marks = " / ".join(f"{at[s]:.2f}" if s in at else "-" for s in (100_000, 200_000, 300_000))
        reached = f"{r['steps_to_target']:,}" if r["steps_to_target"] else "not reached"
        lines.append(
            f"| {r['run']} | {ARMS[arm][0]} | {r['env_steps']:,} | {r['hours']:.2f} | {r['updates_per_s']:.1f} | {marks} | "
            f"{r['best_success']:.2f} | {reached} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--arms", nargs="+", default=list(DEFAULT_ARMS), choices=list(ARMS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--budget", type=int, default=300_000, help="env steps per arm")
    parser.add_argument("--hours", type=float, default=0.0, help="stop each arm after this long in this sitting (0: no limit)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--report", action="store_true", help="train nothing; report the runs as they stand")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--figure", type=Path, default=HERE / "figures" / "qtopt_ablation_fetchpush.png")
    parser.add_argument(
        "--diagnose",
        type=int,
        default=0,
        metavar="EPISODES",
        help="also measure each arm's last checkpoint with qtopt_diagnose.py over this many greedy episodes",
    )
    parser.add_argument("--trained-with", default="", help="the training commands, for the written section")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if not args.report:
        with ProcessPoolExecutor(args.workers) as pool:
            n = len(args.arms)
            list(pool.map(run_arm, args.arms, [args.seed] * n, [args.budget] * n, [args.hours] * n, [args.out] * n))
    present = [a for a in args.arms if (args.out / f"{a}-s{args.seed}" / "metrics.csv").exists()]
    results = [summarise(args.out / f"{a}-s{args.seed}") for a in present]
    (HERE / "results" / "qtopt_ablation_fetchpush.json").write_text(json.dumps(results, indent=2))
    curves_png(results, args.figure)
    text = table(results, present)
    if args.diagnose:
        from qtopt_diagnose import diagnose
        from qtopt_diagnose import table as diagnose_table

        found = [diagnose(args.out / f"{a}-s{args.seed}", args.diagnose) for a in present]
        (HERE / "results" / "qtopt_diagnose_fetchpush.json").write_text(json.dumps(found, indent=2))
        text += (
            f"\n\nEach arm's last checkpoint measured by `qtopt_diagnose.py` over {args.diagnose} greedy episodes "
            "(see its docstring for each column):\n\n" + diagnose_table(found)
        )
    if args.trained_with:
        text = f"Trained with {args.trained_with}.\n\n{text}"
    print(text)
    if args.write:
        from common import append_results

        append_results(
            "QT-Opt + HER on FetchPush-v4: one change at a time",
            f"Arms of `{PRESET}` as it stood before bounded Q (8 copies, 128x128 Q-network, 0.1 updates per env step, "
            "relabelling future k = 4), each changed as its row says (a row that names another preset starts from it), "
            f"seed {args.seed}, up to {args.budget:,} env steps each (or the hours given), one torch thread per arm, "
            f"{args.workers} arms at a time; "
            f"evaluation: 100 episodes every 25k env steps, success at the final step. "
            f"Curves: `benchmarks/figures/{args.figure.name}`.\n\n{text}",
        )


if __name__ == "__main__":
    main()
