"""QT-Opt + HER learning to push: today's defaults against QT-Opt as it was, and SAC with the same network and ratio.

Two tasks (``--task``): ``pixelpush`` (PixelPush from positions, ``pixelpush-state-qtopt-her``: the five-minute
question) and ``fetchpush`` (FetchPush-v4, ``fetchpush-qtopt-her``: hours). Arms:

- ``defaults``: QT-Opt's defaults with the Huber loss, as they stood before the squared loss became the goal-env
  presets' loss (the arm keeps its name so its earlier run folders resume): the Bellman maximum over one CEM round of
  32 candidates, truncated CEM samples, noise 0.2 around the CEM action and 30% random actions throughout,
  independent twins;
- ``before``: QT-Opt as it was before those defaults (targets by the acting CEM's 2 x 64, clipped samples, no
  noise, random actions 0.3 -> 0.1 over 20k env steps, lagged twins; the Huber loss);
- ``lagged``, ``paper-maximum``: the ``defaults`` arm with one piece as it was (lagged twins; the 2 x 64 target search);
- ``mse``: the presets as they are: the ``defaults`` arm with a squared loss in place of the Huber loss (offline on
  SAC's FetchPush replay it learnt as fast as SAC: RESULTS, "FetchPush: each learner offline on each learner's data");
- ``sac``: SAC + HER (the task's SAC preset) with QT-Opt's network and update ratio.

Each run is its own process with one torch thread (``--workers`` at a time); a run directory holding checkpoints is
resumed (``--hours`` stops each after that long in this sitting); ``--report`` trains nothing. The table gives each
run's env steps to 0.9, its success at fixed points, its update and env-step rates, and QT-Opt's diagnostics
(share of stored action components on a bound, spread of Q over candidate actions, how often the twin minimum
clips) at the ``--marks``. Raw curves: ``benchmarks/results/qtopt_push_<task>.json``.

    .venv/bin/python benchmarks/qtopt_push.py --task pixelpush --seeds 0 1 --workers 2 --write
    .venv/bin/python benchmarks/qtopt_push.py --task fetchpush --arms mse sac --seeds 0 1 --budget 1000000 --hours 1.4
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
TARGET = 0.9
BEFORE = {
    "twin": "lagged",
    "noise_std": 0.0,
    "random_action_prob": 0.3,
    "random_action_prob_end": 0.1,
    "random_action_decay_steps": 20_000,
    "truncate": False,
    "target_samples": 64,
    "target_iterations": 2,
    "target_elites": 6,
    "loss": "huber",
}
HUBER = {"loss": "huber"}  # the presets' loss until the squared loss replaced it
ARMS = {
    "defaults": ("QT-Opt's defaults with the Huber loss (the presets before the squared loss)", HUBER),
    # reported, not re-runnable: the noise has followed `cem.truncate` since
    "clipped-noise": ("the Huber defaults with exploration noise clipped to the box (commit d15eae3)", HUBER),
    "before": ("QT-Opt as it was (2 x 64 target search, clipped samples, no noise, 0.3 -> 0.1 random, lagged)", BEFORE),
    "lagged": ("the Huber defaults with lagged twins", {**HUBER, "twin": "lagged"}),
    "paper-maximum": (
        "the Huber defaults with the paper's 2 x 64 target search",
        {**HUBER, "target_samples": 64, "target_iterations": 2, "target_elites": 6},
    ),
    "mse": ("QT-Opt's defaults: the squared loss (SAC's critic loss)", {"loss": "mse"}),
    "sac": ("SAC + HER with QT-Opt's network and update ratio", {}),
}
#: the QT-Opt loss of the arms whose run names do not say it (the figure's legend)
LOSSES = {"defaults": "Huber loss", "mse": "squared loss"}
#: task -> (QT-Opt preset, SAC preset, evaluation marks in env steps, default budget)
TASKS = {
    "pixelpush": ("pixelpush-state-qtopt-her", "pixelpush-state-sac-her", (50_000, 100_000, 150_000), 150_000),
    "fetchpush": ("fetchpush-qtopt-her", "fetchpush-sac-her", (100_000, 300_000, 500_000, 1_000_000), 1_000_000),
}
DIAGNOSTICS = ("action_on_bound", "q_spread", "twin_clip_rate")


def run_arm(task: str, arm: str, seed: int, budget: int, hours: float, root: str) -> str:
    import torch

    import taskrl
    from taskrl.presets import preset_config

    torch.set_num_threads(1)
    qtopt, sac, *_ = TASKS[task]
    out = Path(root) / f"{arm}-s{seed}"
    overrides = {"total_steps": budget, "tensorboard": False, "threads": 1, "stop_at_success": 0.0}
    if hours:
        overrides["max_hours"] = hours
    if (out / "checkpoints").exists():
        taskrl.train(resume=out, **overrides)
    elif arm == "sac":  # the same network and update ratio as QT-Opt's preset
        q = preset_config(qtopt)
        shape = {"hidden_sizes": q.algo_settings.hidden_sizes, "updates_per_step": q.updates_per_step}
        taskrl.train(sac, out=out, seed=seed, **shape, **overrides)
    else:
        taskrl.train(qtopt, out=out, seed=seed, **ARMS[arm][1], **overrides)
    return str(out)


def summarise(run_dir: Path, marks: tuple[int, ...]) -> dict:
    import statistics

    from taskrl.logger import read_metrics

    rows = [r for r in read_metrics(run_dir / "metrics.csv") if r["success_rate"] is not None]
    reached = next((r for r in rows if r["success_rate"] >= TARGET), None)
    learning = [r for r in rows if r.get("updates_per_s")]

    def at(mark: int) -> dict | None:
        return next((r for r in rows if r["env_steps"] >= mark), None)

    return {
        "run": run_dir.name,
        "env_steps": rows[-1]["env_steps"],
        "hours": rows[-1]["wall_seconds"] / 3600,
        "steps_to_target": reached["env_steps"] if reached else None,
        "best_success": max(r["success_rate"] for r in rows),
        "updates_per_s": statistics.median(r["updates_per_s"] for r in learning) if learning else 0.0,
        "env_steps_per_s": rows[-1]["env_steps"] / max(rows[-1]["wall_seconds"], 1e-9),
        "marks": {m: {k: at(m).get(k) for k in ("success_rate", *DIAGNOSTICS)} if at(m) else None for m in marks},
        "curve": [(r["env_steps"], r["success_rate"]) for r in rows],
    }


def earlier(spec: str, marks: tuple[int, ...]) -> dict:
    """``FILE:RUN``: a run kept only as a raw curve of another benchmark (``qtopt_ablation.py``'s format: ``curve`` of
    ``(env steps, hours, success)``), summarised as :func:`summarise` does; its name gets ``(earlier)``."""
    path, _, name = spec.rpartition(":")
    entry = next(r for r in json.loads(Path(path).read_text()) if r["run"] == name)
    curve = [(int(steps), success) for steps, _, success in entry["curve"]]

    def at(mark: int) -> dict | None:
        return next(({"success_rate": v} for s, v in curve if s >= mark), None)

    return {
        "run": f"sac-s{entry['seed']} (earlier)",
        "env_steps": entry["env_steps"],
        "hours": entry["hours"],
        "steps_to_target": next((s for s, v in curve if v >= TARGET), None),
        "best_success": max(v for _, v in curve),
        "updates_per_s": entry["updates_per_s"],
        "env_steps_per_s": entry["env_steps_per_s"],
        "marks": {m: at(m) for m in marks},
        "curve": curve,
    }


def figure(results: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    colours: dict[str, str] = {}
    for r in results:
        arm = r["run"].rsplit("-s", 1)[0]
        steps, success = zip(*r["curve"])
        label = f"{r['run']} ({LOSSES[arm]})" if arm in LOSSES else r["run"]
        line = ax.plot([s / 1e3 for s in steps], success, marker=".", color=colours.get(arm), label=label)[0]
        colours.setdefault(arm, line.get_color())
    ax.axhline(TARGET, color="grey", linestyle="--", linewidth=0.8)
    ax.set_xlabel("env steps (thousands)")
    ax.set_ylabel("evaluation success")
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def _cell(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def table(results: list[dict], marks: tuple[int, ...]) -> str:
    head = " / ".join(f"{m // 1000}k" for m in marks)
    lines = [
        f"| run | what | env steps | hours | updates/s | env steps/s | success at {head} | best | env steps to 0.9 |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        arm = r["run"].rsplit("-s", 1)[0]
        what = ARMS[arm][0] + (" (an earlier run: see the note)" if "earlier" in r["run"] else "")
        success = " / ".join(_cell(r["marks"][m]["success_rate"]) if r["marks"][m] else "-" for m in marks)
        reached = f"{r['steps_to_target']:,}" if r["steps_to_target"] else "not reached"
        lines.append(
            f"| {r['run']} | {what} | {r['env_steps']:,} | {r['hours']:.2f} | {r['updates_per_s']:.0f} | "
            f"{r['env_steps_per_s']:.0f} | {success} | {r['best_success']:.2f} | {reached} |"
        )
    lines += [
        "",
        f"Diagnostics at {head} env steps (QT-Opt runs; each the mean over that metrics row's updates): share of stored "
        "action components on a bound / standard deviation of Q over the target search's first candidates / share of "
        "rows where the twin minimum clips.",
        "",
        "| run | on a bound | Q spread | twin clips |",
        "|---|---|---|---|",
    ]
    for r in results:
        if r["run"].startswith("sac"):
            continue
        cols = [" / ".join(_cell(r["marks"][m].get(k), 3) if r["marks"][m] else "-" for m in marks) for k in DIAGNOSTICS]
        lines.append(f"| {r['run']} | " + " | ".join(cols) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--task", choices=list(TASKS), default="pixelpush")
    parser.add_argument(
        "--arms", nargs="+", default=["mse", "defaults", "before", "lagged", "paper-maximum", "sac"], choices=list(ARMS)
    )
    parser.add_argument("--note", default="", help="a note for the written section (where runs came from)")
    parser.add_argument(
        "--earlier", nargs="*", default=[], metavar="FILE:RUN", help="also report runs kept only as another benchmark's curve"
    )
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--budget", type=int, default=0, help="env steps per run (0: the task's default)")
    parser.add_argument("--hours", type=float, default=0.0, help="stop each run after this long in this sitting (0: none)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=None, help="folder of the runs (default benchmarks/out/qtopt_push_TASK)")
    parser.add_argument("--report", action="store_true", help="train nothing; report the runs as they stand")
    parser.add_argument("--write", action="store_true", help="write the RESULTS section, the figure and the raw data")
    args = parser.parse_args()
    qtopt, _, marks, default_budget = TASKS[args.task]
    budget = args.budget or default_budget
    out = args.out or HERE / "out" / f"qtopt_push_{args.task}"
    out.mkdir(parents=True, exist_ok=True)
    runs = [(arm, seed) for seed in args.seeds for arm in args.arms]
    if not args.report:
        with ProcessPoolExecutor(args.workers) as pool:
            jobs = [pool.submit(run_arm, args.task, a, s, budget, args.hours, str(out)) for a, s in runs]
            for job in jobs:
                job.result()
    present = [out / f"{a}-s{s}" for a, s in runs if (out / f"{a}-s{s}" / "metrics.csv").exists()]
    results = [summarise(p, marks) for p in present] + [earlier(spec, marks) for spec in args.earlier]
    text = table(results, marks)
    print(text)
    if args.write:
        from common import append_results

        name = f"qtopt_push_{args.task}"
        (HERE / "results" / f"{name}.json").write_text(json.dumps(results, indent=2))
        title = f"QT-Opt + HER learning to push ({args.task}): defaults, QT-Opt as it was, SAC alike"
        figure(results, HERE / "figures" / f"{name}.png", title)
        append_results(
            title,
            f"`{qtopt}` with each arm's settings (the `sac` arm: the task's SAC preset with QT-Opt's network and update "
            f"ratio), seeds {args.seeds}, up to {budget:,} env steps (or the hours given), one torch thread per run, "
            f"{args.workers} runs at a time. Raw data: `benchmarks/results/{name}.json`.{' ' + args.note if args.note else ''}\n\n"
            f"![curves](figures/{name}.png)\n\n{text}",
        )


if __name__ == "__main__":
    main()
