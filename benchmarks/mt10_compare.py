"""Meta-World MT10 side by side: one-hot vs FiLM-language vs CARE (multi-task SAC) vs PPO one-hot.

Every method trains on MT10 (one copy per task, goals resampled every episode) for the same
``--budget`` env steps in total (``budget / 10`` per task), for each seed, using its preset
(``mt10-sac-onehot``, ``mt10-sac-film-language``, ``mt10-sac-care``, ``mt10-ppo-onehot``) with the
network narrowed to ``--hidden`` and SAC's batch to ``--batch-size`` so the whole comparison fits a
few hours of two CPU cores. Evaluation follows Meta-World's protocol (``--eval-episodes`` distinct
goal positions per task, success at any step; headline = mean over tasks). Runs go to
``benchmarks/out/mt10/<preset>-s<seed>`` and run ``--workers`` at a time (one torch thread each).

Written: the per-task success table (mean over seeds), the mean over tasks per seed, training
throughput, and learning curves (``benchmarks/figures/mt10_curves.png``). ``--profile`` also
measures the share of a training step spent in simulation versus learning at the preset's scale.

    .venv/bin/python benchmarks/mt10_compare.py --budget 200000 --seeds 0 1 --workers 2 --profile --write
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

METHODS = ("mt10-sac-onehot", "mt10-sac-film-language", "mt10-sac-care", "mt10-ppo-onehot")
HERE = Path(__file__).resolve().parent
OUT = HERE / "out" / "mt10"


def run_one(
    preset: str,
    seed: int,
    budget: int,
    hidden: tuple[int, ...],
    batch_size: int,
    eval_interval: int,
    eval_episodes: int,
    root: Path = OUT,
) -> dict:
    import torch

    import taskrl

    torch.set_num_threads(1)
    out = root / f"{preset}-s{seed}"
    overrides = dict(
        seed=seed,
        total_steps=budget,
        hidden_sizes=hidden,
        eval_interval=eval_interval,
        eval_episodes=eval_episodes,
        checkpoint_interval=10**12,
        save_replay=False,
        tensorboard=False,
    )
    if "ppo" not in preset:
        overrides["batch_size"] = batch_size
    if not (out / "per_task_success.json").exists():  # a finished run is reused; an unfinished one restarts
        shutil.rmtree(out, ignore_errors=True)
        taskrl.train(preset, out=out, **overrides)
    from taskrl.logger import read_metrics

    rows = read_metrics(out / "metrics.csv")
    per_task = json.loads((out / "per_task_success.json").read_text())
    last = rows[-1]
    learn_rows = [r for r in rows if r["env_steps"] and r["updates_per_s"]]
    return {
        "preset": preset,
        "seed": seed,
        "mean_success": per_task["mean_success_rate"],
        "tasks": {k: v["success_rate"] for k, v in per_task["tasks"].items()},
        "wall_seconds": last["wall_seconds"],
        "env_steps": last["env_steps"],
        "updates": last["updates"],
        "env_steps_per_s": last["env_steps"] / max(last["wall_seconds"], 1e-9),
        "updates_per_s": statistics.median(r["updates_per_s"] for r in learn_rows) if learn_rows else 0.0,
        "curve": [(r["env_steps"], r["success_rate"]) for r in rows],
    }


def profile(seconds: float = 20.0) -> str:
    """Simulation vs learning per env step, at the mt10-sac-onehot preset's own scale."""
    import torch

    from taskrl.plan import validate
    from taskrl.presets import preset_config
    from taskrl.replay.batch import Batch
    from taskrl.run import make_agent, make_env

    torch.set_num_threads(1)
    lines = [
        "| preset scale | sim ms / env step (10 copies, random actions) | act ms / env step | ms / update | "
        "updates per env step | learning share of a training step | env steps/s implied |",
        "|---|---|---|---|---|---|---|",
    ]
    for preset, hidden, batch in (("mt10-sac-onehot", (400, 400, 400), 1280), ("mt10-sac-onehot", (256, 256), 640)):
        config = validate(preset_config(preset))
        config.algo_settings.hidden_sizes = hidden
        env = make_env(config, "cpu", num_envs=10, seed=0)
        agent = make_agent(config, env, torch.device("cpu"))
        obs = env.reset(seed=0)
        low, high = (torch.as_tensor(b) for b in (env.single_action_space.low, env.single_action_space.high))
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds / 4:
            obs, *_ = env.step(low + (high - low) * torch.rand(10, low.numel()))
            steps += 10
        sim = (time.perf_counter() - start) / steps * 1e3
        start, acts = time.perf_counter(), 0
        while time.perf_counter() - start < seconds / 8:
            agent.act(obs, explore=True)
            acts += 1
        act = (time.perf_counter() - start) / (acts * 10) * 1e3
        idx = torch.randint(10, (batch,))
        o = {k: v[idx] for k, v in obs.items()}
        b = Batch(
            obs=o,
            action=torch.rand(batch, 4) * 2 - 1,
            reward=torch.rand(batch),
            next_obs=o,
            terminated=torch.zeros(batch, dtype=torch.bool),
            truncated=torch.zeros(batch, dtype=torch.bool),
            episode=idx,
            step=idx,
        )
        agent.update(b)
        start, updates = time.perf_counter(), 0
        while time.perf_counter() - start < seconds / 2:
            agent.update(b)
            updates += 1
        upd = (time.perf_counter() - start) / updates * 1e3
        env.close()
        ratio = config.updates_per_step
        learn = ratio * upd
        lines.append(
            f"| {hidden}, batch {batch} | {sim:.2f} | {act:.2f} | {upd:.1f} | {ratio} | "
            f"{learn / (learn + sim + act):.0%} | {1e3 / (learn + sim + act):.0f} |"
        )
    return "\n".join(lines)


def curves_png(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for preset in METHODS:
        runs = [r for r in results if r["preset"] == preset]
        if not runs:
            continue
        steps = [s for s, _ in runs[0]["curve"]]
        n = min(len(r["curve"]) for r in runs)
        mean = [statistics.mean(r["curve"][i][1] for r in runs) for i in range(n)]
        ax.plot(steps[:n], mean, marker="o", label=f"{preset} ({len(runs)} seeds)")
    ax.set_xlabel("env steps (all 10 tasks)")
    ax.set_ylabel("mean success over tasks")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Meta-World MT10")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--budget", type=int, default=200_000, help="env steps in total (all tasks)")
    parser.add_argument("--hidden", type=int, nargs="+", default=[256, 256])
    parser.add_argument("--batch-size", type=int, default=640, help="SAC batch (task-balanced: batch / 10 per task)")
    parser.add_argument("--eval-interval", type=int, default=50_000)
    parser.add_argument("--eval-episodes", type=int, default=10, help="distinct goals per task per evaluation")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--out", type=Path, default=OUT, help="run directories (a finished run there is reused)")
    parser.add_argument("--figure", type=Path, default=HERE / "figures" / "mt10_curves.png")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    args.figure.parent.mkdir(parents=True, exist_ok=True)
    jobs = [
        (p, s, args.budget, tuple(args.hidden), args.batch_size, args.eval_interval, args.eval_episodes, args.out)
        for s in args.seeds
        for p in args.methods
    ]
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(run_one, *zip(*jobs)))
    (args.out / "results.json").write_text(json.dumps(results, indent=2))
    curves_png(results, args.figure)

    tasks = list(results[0]["tasks"])
    methods = [m for m in args.methods if any(r["preset"] == m for r in results)]
    per_task = ["| task | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]
    for task in tasks:
        cells = [statistics.mean(r["tasks"][task] for r in results if r["preset"] == m) for m in methods]
        per_task.append(f"| {task} | " + " | ".join(f"{c:.2f}" for c in cells) + " |")
    means = [statistics.mean(r["mean_success"] for r in results if r["preset"] == m) for m in methods]
    per_task.append("| **mean over tasks** | " + " | ".join(f"**{m:.2f}**" for m in means) + " |")
    summary = ["| method | seed | mean success | training seconds | env steps/s | updates/s |", "|---|---|---|---|---|---|"]
    for r in results:
        summary.append(
            f"| {r['preset']} | {r['seed']} | {r['mean_success']:.2f} | {r['wall_seconds']:.0f} | "
            f"{r['env_steps_per_s']:.0f} | {r['updates_per_s']:.0f} |"
        )
    text = "\n".join(summary) + "\n\nPer-task success (mean over seeds):\n\n" + "\n".join(per_task)
    if args.profile:
        text += "\n\nWhere a training step's time goes (measured in isolation, one torch thread):\n\n" + profile()
    print(text)
    if args.write:
        from common import append_results

        append_results(
            "Meta-World MT10 side by side",
            f"Budget {args.budget:,} env steps in total ({args.budget // 10:,} per task), seeds {args.seeds}, hidden "
            f"{tuple(args.hidden)}, SAC batch {args.batch_size} (task-balanced), evaluation every {args.eval_interval:,} "
            f"steps on {args.eval_episodes} distinct goals per task (success at any step); {args.workers} runs at a "
            f"time, one torch thread each. Curves: `benchmarks/figures/{args.figure.name}`.\n\n{text}",
        )


if __name__ == "__main__":
    main()
