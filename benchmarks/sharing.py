"""Data sharing between tasks: every strategy over seeds, online (MT-Opt's imbalance) and offline (CDS's
mixed-quality datasets), with per-task success, curves and 95% confidence intervals.

.venv/bin/python benchmarks/sharing.py online --preset grid-sharing-dqn --seeds 0 1 2 3 4 --write
.venv/bin/python benchmarks/sharing.py online --preset point-sharing-sac --seeds 0 1 2 --write
.venv/bin/python benchmarks/sharing.py offline --preset point-sharing-offline --seeds 0 1 2 --write
.venv/bin/python benchmarks/sharing.py costs --write
.venv/bin/python benchmarks/sharing.py offline --seeds 0 1 2 --name corners-expert --write \
    --set dataset_quality=top-left=expert,top-right=expert,bottom-left=expert,bottom-right=expert,centre=random,right-edge=random
.venv/bin/python benchmarks/sharing.py offline --preset grid-sharing-dqn --seeds 0 1 2 --write \
    --sweep cql_alpha 0.03 0.1 0.3 1 3 --sweep-seed 100

``--sweep KEY V1 V2 ...`` first runs every value for every strategy on ``--sweep-seed`` (a seed the table
does not use), keeps per strategy the value with the highest mean success, then runs the table's seeds at
each strategy's own value.

Each run is the preset with ``--sharing S`` (and the overrides given with ``--set KEY=VALUE``); the
figures are the final greedy evaluation (``eval_episodes`` per task) and the evaluation curve of
``metrics.csv``. Raw per-seed data go to ``benchmarks/results/sharing_<preset>.json``, the curves
to ``benchmarks/figures/sharing_<preset>.png``.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import statistics
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from common import append_results, command_line, commit

HERE = Path(__file__).parent
ONLINE = ("none", "all", "random", "success", "hipi", "conservative", "zero-reward", "mtopt")
OFFLINE = ("none", "all", "conservative", "zero-reward")
# two-sided 95% Student t quantiles by degrees of freedom
T95 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262}


def interval(values: list[float]) -> tuple[float, float]:
    """Mean and half-width of the 95% t-interval over seeds."""
    mean = statistics.fmean(values)
    if len(values) < 2:
        return mean, math.nan
    return mean, T95.get(len(values) - 1, 1.96) * statistics.stdev(values) / math.sqrt(len(values))


def describe(overrides: dict, name: str) -> str:
    """A section title's words for the overrides: ``--name`` if given, else ``key=value`` (long values by key only;
    the section's command lists them)."""
    if name:
        return name.replace("-", " ")
    return " ".join(f"{k}={v}" if len(str(v)) <= 16 else k for k, v in overrides.items())


def one_run(job: tuple[str, str, int, dict]) -> dict:
    import torch

    import taskrl
    from taskrl.envs.reward_tasks import split_names

    preset, strategy, seed, overrides = job
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        run = taskrl.train(
            preset, out=Path(tmp) / "run", seed=seed, sharing=strategy, tensorboard=False, save_replay=False, **overrides
        )
        rows = list(csv.DictReader(open(run.run_dir / "metrics.csv")))
    tasks = [k.split("/", 1)[1] for k in rows[-1] if k.startswith("success/")]
    axis = "updates" if run.config.data.offline else "env_steps"
    curve = [{"at": int(float(r[axis])), **{t: float(r[f"success/{t}"]) for t in tasks}} for r in rows]
    shared = {t: float(rows[-1].get(f"shared/{t}") or 0.0) for t in tasks}
    low = split_names(getattr(run.config.env_settings, "low_data_tasks", ""))
    return {
        "preset": preset,
        "strategy": strategy,
        "seed": seed,
        "axis": axis,
        "low_data_tasks": low,
        "final": {t: curve[-1][t] for t in tasks},
        "mean_success": run.metrics["success_rate"],
        "shared_at_end": shared,
        "wall_seconds": run.metrics["wall_seconds"],
        # what the replay held at the last evaluation (datasets and completed episodes) and had dropped
        "replay_transitions": int(float(rows[-1].get("replay_transitions") or 0)),
        "replay_evicted": int(float(rows[-1].get("replay_evicted") or 0)),
        "curve": curve,
    }


def plot(results: list[dict], strategies: list[str], focus: list[str], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(focus), figsize=(5 * len(focus), 3.6), squeeze=False)
    for ax, task in zip(axes[0], focus):
        for strategy in strategies:
            runs = [r for r in results if r["strategy"] == strategy]
            at = [p["at"] for p in runs[0]["curve"]]
            values = [
                [(p[task] if task != "mean" else statistics.fmean(v for k, v in p.items() if k != "at")) for p in r["curve"]]
                for r in runs
            ]
            mean = [statistics.fmean(col) for col in zip(*values)]
            low = [min(col) for col in zip(*values)]
            high = [max(col) for col in zip(*values)]
            (line,) = ax.plot(at, mean, label=strategy)
            ax.fill_between(at, low, high, alpha=0.15, color=line.get_color())
        ax.set_title(f"{task} (mean over seeds; band: min-max)")
        ax.set_xlabel(results[0]["axis"].replace("_", " "))
        ax.set_ylabel("success")
        ax.set_ylim(-0.02, 1.02)
    axes[0][-1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def at_point(run: dict, at: int | None) -> dict[str, float]:
    """Per-task success at the evaluation nearest ``at`` (the final one when None), with ``all tasks``."""
    point = run["curve"][-1] if at is None else min(run["curve"], key=lambda p: abs(p["at"] - at))
    tasks = {k: v for k, v in point.items() if k != "at"}
    return {**tasks, "all tasks": statistics.fmean(tasks.values())}


def table(results: list[dict], strategies: list[str], columns: list[str], at: int | None = None) -> str:
    head = "| strategy | " + " | ".join(columns) + " | per seed (" + columns[0] + ") |"
    lines = [head, "|---" * (len(columns) + 2) + "|"]
    for strategy in strategies:
        runs = sorted((r for r in results if r["strategy"] == strategy), key=lambda r: r["seed"])
        cells = []
        for column in columns:
            values = [at_point(r, at)[column] for r in runs]
            mean, half = interval(values)
            cells.append(f"{mean:.2f} ± {half:.2f}")
        first = [at_point(r, at)[columns[0]] for r in runs]
        lines.append(f"| {strategy} | " + " | ".join(cells) + " | " + ", ".join(f"{v:.2f}" for v in first) + " |")
    return "\n".join(lines)


OFFLINE_INDEX = HERE / "results" / "sharing_offline_index.json"
OFFLINE_TITLE = "Data sharing, offline: every setting in one table"


def offline_summary() -> str:
    """One table of every offline setting measured (``results/sharing_offline_index.json`` lists them with where and
    how they ran): the mean success over all tasks and over the tasks whose dataset is expert, per strategy."""
    index = json.loads(OFFLINE_INDEX.read_text())

    def cell(values: list[float]) -> str:
        mean, half = interval(values)
        return f"{mean:.2f} ± {half:.2f}"

    head = "| setting | seeds | " + " | ".join(OFFLINE) + " |"
    rule = "|---" * (len(OFFLINE) + 2) + "|"
    every, expert, provenance, figures = [head, rule], [head, rule], [], []
    for raw, entry in index.items():
        results = json.loads((HERE / "results" / raw).read_text())
        seeds = len({r["seed"] for r in results})
        picked = entry.get("picked_cql_alpha")
        setting = entry["setting"] + (" (" + ", ".join(f"{k} {v:g}" for k, v in picked.items()) + ")" if picked else "")
        cells_all, cells_expert = [], []
        for strategy in OFFLINE:
            runs = [r for r in results if r["strategy"] == strategy]
            cells_all.append(cell([at_point(r, None)["all tasks"] for r in runs]) if runs else "-")
            scores = [statistics.fmean(at_point(r, None)[t] for t in entry["expert_tasks"]) for r in runs]
            cells_expert.append(cell(scores) if runs else "-")
        every.append(f"| {setting} | {seeds} | " + " | ".join(cells_all) + " |")
        expert.append(f"| {setting} ({', '.join(entry['expert_tasks'])}) | {seeds} | " + " | ".join(cells_expert) + " |")
        provenance.append(f"| {entry['setting']} | {entry['commit']} | {entry['date']} | `{entry['command']}` |")
        figure = raw.replace(".json", ".png")
        figures.append(f"![{entry['setting']}](figures/{figure})")
    return (
        "Final greedy success after each setting's budget, mean ± 95% t-interval half-width over seeds, one torch "
        "thread per run, 2 runs at once (CDS's question: does sharing help or hurt, and the task with expert data in "
        "particular). Per-task figures and curves: the raw data `benchmarks/results/sharing_<setting>.json`.\n\n"
        "Mean over all tasks:\n\n"
        + "\n".join(every)
        + "\n\nMean over the tasks whose dataset is expert:\n\n"
        + "\n".join(expert)
        + "\n\nWhere each setting ran (machine: 2 cores, AMD EPYC, Linux, Python 3.11.7, torch 2.13.0+cpu):\n\n"
        "| setting | measured at commit | date | command |\n|---|---|---|---|\n"
        + "\n".join(provenance)
        + "\n\nCurves (mean over seeds; band: min-max):\n\n"
        + "\n\n".join(figures)
    )


def sampler_costs(transitions: int, batch_size: int, calls: int) -> str:
    """ms per batch of each strategy's sampler against plain task-balanced sampling and a DQN update,
    on a replay of random grid episodes."""
    import time

    import torch

    from taskrl.agents.dqn import DQNAgent, DQNConfig
    from taskrl.envs.grid_tasks import GridTasks
    from taskrl.replay import EpisodeReplay, TaskBalancedSampler
    from taskrl.sharing import SharingConfig, TaskSharing
    from taskrl.sharing.datasets import random_actions

    torch.set_num_threads(1)
    env = GridTasks(num_envs=64, seed=0)
    replay = EpisodeReplay(
        env.single_observation_space, env.single_action_space, transitions * 2, num_envs=64, horizon=env.horizon
    )
    generator = torch.Generator().manual_seed(0)
    obs = env.reset(seed=0)
    replay.start(obs)
    for _ in range(transitions // 64):
        action = random_actions(env.single_action_space, 64, generator, env.device)
        next_obs, reward, terminated, truncated, info = env.step(action)
        replay.add(action, reward, terminated, truncated, info["final_obs"], next_obs)
        obs = next_obs
    agent = DQNAgent(("observation",), 49, 5, DQNConfig(hidden_sizes=(128,)))

    def timed(fn) -> float:
        for _ in range(10):
            fn()
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        return (time.perf_counter() - start) / calls * 1e3

    balanced = TaskBalancedSampler(replay, env.num_tasks)
    rows = [f"| task-balanced (no sharing) | {timed(lambda: balanced(batch_size, generator)):.2f} |"]
    for strategy in ONLINE:
        sharing = TaskSharing(
            replay, env, env.num_tasks, SharingConfig(sharing=strategy), q_value=lambda o, a: o["observation"][:, 0]
        )
        rows.append(f"| {strategy} | {timed(lambda sample=sharing: sample(batch_size, generator)):.2f} |")
    batch = balanced(batch_size, generator)
    rows.append(f"| (a DQN update, 49-128-5, for scale) | {timed(lambda: agent.update(batch)):.2f} |")
    head = (
        f"{replay.num_transitions:,} stored transitions in {replay.num_episodes:,} episodes, batch {batch_size}, "
        f"mean over {calls} calls; `conservative` with a stand-in Q (a column of the observation), "
        "so its cost excludes the agent's forward passes.\n\n| sampler | ms per batch |\n|---|---|"
    )
    return head + "\n" + "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "setting",
        choices=("online", "offline", "table", "costs", "summary"),
        help="table: re-read --results at --at; costs: ms per batch; summary: the offline settings' one table again",
    )
    parser.add_argument("--results", type=Path, help="table: a results JSON of an earlier run")
    parser.add_argument("--at", type=int, default=None, help="table: the evaluation nearest this step or update")
    parser.add_argument("--preset", default=None)
    parser.add_argument("--strategies", nargs="+", default=None)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--jobs", type=int, default=2, help="runs at once (one torch thread each)")
    parser.add_argument("--set", nargs="*", default=[], help="overrides KEY=VALUE (numbers parsed)")
    parser.add_argument("--name", default="", help="suffix of the result files (default: the overrides)")
    parser.add_argument("--sweep", nargs="+", default=None, help="KEY V1 V2 ...: pick a value per strategy first")
    parser.add_argument("--sweep-seed", type=int, default=100, help="the seed of the --sweep runs")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    if args.setting == "summary":
        text = offline_summary()
        print(text)
        if args.write:
            append_results(OFFLINE_TITLE, text)
        return
    if args.setting == "costs":
        text = sampler_costs(100_000, 256, 200)
        print(text)
        if args.write:
            append_results("Data sharing: sampler cost per batch", text)
        return
    if args.setting == "table":
        results = json.loads(args.results.read_text())
        strategies = list(dict.fromkeys(r["strategy"] for r in results))
        low = results[0]["low_data_tasks"]
        print(table(results, strategies, [*(low or list(results[0]["final"])), "all tasks"], args.at))
        return
    preset = args.preset or ("grid-sharing-dqn" if args.setting == "online" else "point-sharing-offline")
    strategies = args.strategies or list(ONLINE if args.setting == "online" else OFFLINE)
    overrides = {}
    for item in args.set:
        key, _, value = item.partition("=")
        try:
            overrides[key] = json.loads(value)
        except json.JSONDecodeError:
            overrides[key] = value
    per_strategy = {s: dict(overrides) for s in strategies}
    sweep_text = ""
    if args.sweep:
        key, values = args.sweep[0], [json.loads(v) for v in args.sweep[1:]]
        sweep_jobs = [(preset, s, args.sweep_seed, {**overrides, key: v}) for s in strategies for v in values]
        with ProcessPoolExecutor(args.jobs) as pool:
            swept = list(pool.map(one_run, sweep_jobs))
        sweep_text = f"Sweep of `{key}` on seed {args.sweep_seed} (mean success over all tasks):\n\n"
        sweep_text += "| strategy | " + " | ".join(f"{key}={v}" for v in values) + " | picked |\n"
        sweep_text += "|---" * (len(values) + 2) + "|\n"
        for s in strategies:
            scores = [at_point(r, None)["all tasks"] for r in swept if r["strategy"] == s]
            # ties go to the first (smallest) value listed
            best = values[max(range(len(values)), key=lambda i: (scores[i], -i))]
            per_strategy[s][key] = best
            sweep_text += f"| {s} | " + " | ".join(f"{v:.2f}" for v in scores) + f" | {best} |\n"
        print(sweep_text, flush=True)
    jobs = [(preset, s, seed, per_strategy[s]) for s in strategies for seed in args.seeds]
    with ProcessPoolExecutor(args.jobs) as pool:
        results = []
        for result in pool.map(one_run, jobs):
            print(json.dumps({k: v for k, v in result.items() if k != "curve"}), flush=True)
            results.append(result)
    tasks = list(results[0]["final"])
    low = results[0]["low_data_tasks"]
    if args.setting == "online":
        columns = [*low, "all tasks"]
    else:
        columns = [*tasks, "all tasks"]
    text = table(results, strategies, columns)
    print(text)
    if args.write:
        suffix = args.name or "_".join(f"{k}-{v}" for k, v in overrides.items())
        if args.sweep and not args.name:
            suffix = "_".join(filter(None, [suffix, f"sweep-{args.sweep[0]}"]))
        name = preset + (f"_{suffix}" if suffix else "")
        (HERE / "results").mkdir(exist_ok=True)
        (HERE / "figures").mkdir(exist_ok=True)
        (HERE / "results" / f"sharing_{name}.json").write_text(json.dumps(results, indent=1) + "\n")
        figure = HERE / "figures" / f"sharing_{name}.png"
        plot(results, strategies, [*(low or tasks[:2]), "mean"], figure)
        index = json.loads(OFFLINE_INDEX.read_text()) if OFFLINE_INDEX.exists() else {}
        if args.setting == "offline":  # one table for every offline setting; this run's row added or replaced
            quality = per_strategy[strategies[0]].get("dataset_quality") or preset_dataset_quality(preset)
            index[f"sharing_{name}.json"] = {
                "setting": f"{preset}{', ' + describe(overrides, args.name) if overrides or args.name else ''}",
                "commit": commit(),
                "date": __import__("datetime").date.today().isoformat(),
                "command": command_line(),
                "expert_tasks": [k for k, q in (x.split("=") for x in quality.split(",")) if q == "expert"],
                **({"picked_cql_alpha": {s: per_strategy[s][args.sweep[0]] for s in strategies}} if args.sweep else {}),
            }
            OFFLINE_INDEX.write_text(json.dumps(index, indent=1) + "\n")
            append_results(OFFLINE_TITLE, offline_summary())
            return
        axis = results[0]["axis"].replace("_", " ")
        append_results(
            f"Data sharing, {args.setting}: {preset}{', ' + describe(overrides, args.name) if overrides else ''}",
            f"Final greedy success after the preset's budget ({results[0]['curve'][-1]['at']:,} {axis}), "
            f"mean ± 95% t-interval half-width over seeds {args.seeds}; one torch thread per run, {args.jobs} runs at once. "
            f"Raw per-seed data and curves: `benchmarks/results/sharing_{name}.json`. The replay held "
            f"{statistics.fmean(r['replay_transitions'] for r in results):,.0f} transitions on average at the last "
            f"evaluation and dropped {max(r['replay_evicted'] for r in results):,} at most.\n\n"
            f"![{preset}](figures/{figure.name})\n\n" + text,
        )


def preset_dataset_quality(preset: str) -> str:
    from taskrl.presets import preset_config

    return preset_config(preset).env_settings.dataset_quality


if __name__ == "__main__":
    main()
