"""Distributed training on Ray: per-role throughput, scaling with sleep-bound collectors and updaters,
and time to 90% against the in-process run.

.venv/bin/python benchmarks/distributed.py fetchreach --seeds 0 1 2 --steps 12000 --write
.venv/bin/python benchmarks/distributed.py collectors --counts 1 2 4 8 16 --write
.venv/bin/python benchmarks/distributed.py updaters --counts 1 2 4 8 --write
.venv/bin/python benchmarks/distributed.py fetchpush --steps 50000 --write
.venv/bin/python benchmarks/distributed.py costs --write

Every run is a ``taskrl.train`` call in this process (the trainer); roles are Ray actors of a local
Ray. Raw rows go to ``benchmarks/results/distributed_<part>.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
os.environ["PYTHONPATH"] = os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)  # role processes
import taskrl  # noqa: E402
import taskrl.wiring.calls  # noqa: E402
from common import append_results  # noqa: E402
from taskrl.logger import read_metrics  # noqa: E402

RESULTS = HERE / "results"
QUIET = dict(tensorboard=False, save_replay=False, checkpoint_interval=10**9, checkpoint_minutes=0.0, threads=1)


def _train(preset: str, out: Path, **settings) -> tuple[dict, list[dict], float]:
    started = time.perf_counter()
    run = taskrl.train(preset, out=out, **{**QUIET, **settings})
    return run.metrics, read_metrics(out / "metrics.csv"), time.perf_counter() - started


def _first_at(rows: list[dict], goal: float) -> tuple[int | None, float | None]:
    for row in rows:
        if row["success_rate"] >= goal - 1e-9:
            return row["env_steps"], row["wall_seconds"]
    return None, None


def _window(rows: list[dict], skip: int = 1) -> dict[str, float]:
    """Rates over the rows after the first ``skip`` (start-up excluded), on the training clock."""
    a, b = rows[skip], rows[-1]
    seconds = b["wall_seconds"] - a["wall_seconds"]
    return {
        "seconds": seconds,
        "env_steps_per_s": (b["env_steps"] - a["env_steps"]) / seconds,
        "updates_per_s": (b["updates"] - a["updates"]) / seconds,
    }


def _save(part: str, data: dict) -> None:
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"distributed_{part}.json").write_text(json.dumps(data, indent=1) + "\n")


# ---------------------------------------------------------------------- FetchReach: roles and time to 90%
LAYOUTS = {  # name -> (collectors, bellman updaters); None: in one process
    "in-process": None,
    "1 collector, 1 updater": (1, 1),
    "2 collectors, 1 updater": (2, 1),
    "1 collector, 2 updaters": (1, 2),
    "2 collectors, 2 updaters": (2, 2),
    "2 collectors, trainer's own targets": (2, 0),
}


def fetchreach(args: argparse.Namespace, folder: Path) -> str:
    # --rows-from: rows of runs already made (JSON lines as printed below), e.g. of a benchmark stopped part-way
    rows_out = (
        [json.loads(line) for line in Path(args.rows_from).read_text().splitlines() if line.strip()] if args.rows_from else []
    )
    done = {(r["layout"], r["seed"]) for r in rows_out}
    for name, layout in LAYOUTS.items():
        if args.layouts and name not in args.layouts:
            continue
        for seed in [s for s in args.seeds if (name, s) not in done]:
            cluster = {} if layout is None else dict(distributed=True, collectors=layout[0], bellman_updaters=layout[1])
            metrics, rows, wall = _train(
                "fetchreach-qtopt-her",
                folder / f"{name}-{seed}".replace(" ", "_").replace(",", ""),
                seed=seed,
                total_steps=args.steps,
                stop_at_success=0.9,
                eval_interval=500,
                eval_episodes=50,
                **cluster,
            )
            steps_90, seconds_90 = _first_at(rows, 0.9)
            last = rows[-1]
            entry = {
                "layout": name,
                "seed": seed,
                "env_steps": last["env_steps"],
                "updates": last["updates"],
                "final_success": last["success_rate"],
                "learning_starts": taskrl.wiring.calls.resolve_config("fetchreach-qtopt-her", None, {}).learning_starts,
                "env_steps_to_90": steps_90,
                "training_seconds_to_90": seconds_90,
                "process_seconds": round(wall, 1),
                **{k: v for k, v in _window(rows).items()},
                **{k: last[k] for k in last if "/" in k or k in ("queue_depth", "weight_lag", "updates_per_env_step")},
            }
            rows_out.append(entry)
            print(json.dumps(entry), flush=True)
    _save("fetchreach", {"steps": args.steps, "seeds": args.seeds, "runs": rows_out})
    lines = [
        "| layout | seeds | env steps/s | updates/s | CEM targets/s (all updaters) | env steps/s per collector (while collecting) "
        "| updates per env step | env steps to 90% | training s to 90% |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name in LAYOUTS:
        runs = [r for r in rows_out if r["layout"] == name]
        if not runs:
            continue

        def med(key: str, runs=runs) -> float:
            return statistics.median(r[key] for r in runs)

        per_collector = ", ".join(
            f"{statistics.median(r[k] for r in runs):.0f}"
            for k in sorted(runs[0])
            if k.startswith("collector") and k[9:10].isdigit()
        )
        targets = (
            f"{statistics.median(r.get('updater/targets_per_s', 0) for r in runs):,.0f}"
            if "updater/targets_per_s" in runs[0]
            else "-"
        )
        to90 = [r["env_steps_to_90"] for r in runs]
        secs90 = [r["training_seconds_to_90"] for r in runs]
        lines.append(
            f"| {name} | {len(runs)} | {med('env_steps_per_s'):.0f} | {med('updates_per_s'):.1f} | {targets} | {per_collector or '-'} "
            f"| {statistics.median(r['updates'] / (r['env_steps'] - r['learning_starts']) for r in runs):.3f} "
            f"| {', '.join(str(s) for s in to90)} | {', '.join(f'{s:.0f}' if s is not None else '-' for s in secs90)} |"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------- collectors on a 50 Hz stand-in
def collectors(args: argparse.Namespace, folder: Path) -> str:
    os.environ["SLEEPY_DRIVER_PID"] = str(os.getpid())
    os.environ["SLEEPY_STEP_SECONDS"] = str(args.step_seconds)
    out = []
    for n in args.counts:
        interval = int(n * args.seconds / 6 / args.step_seconds)  # about 6 rows of collection
        metrics, rows, wall = _train(
            "pointreach-sac-her",
            folder / f"collectors-{n}",
            env_id="bench/SleepyPointReach-v0",
            env_module="sleepy_env",
            distributed=True,
            collectors=n,
            envs_per_collector=1,
            collector_steps=25,
            limit_updates=False,
            learning_starts=200,
            total_steps=6 * interval,
            eval_interval=interval,
            eval_episodes=1,
            seed=0,
        )
        entry = {"collectors": n, **_window(rows, skip=2), "process_seconds": round(wall, 1)}
        entry["per_collector_while_collecting"] = statistics.mean(rows[-1][f"collector{i}/env_steps_per_s"] for i in range(n))
        out.append(entry)
        print(json.dumps(entry), flush=True)
    base = out[0]
    for e in out:
        e["of_linear"] = e["env_steps_per_s"] / (base["env_steps_per_s"] * e["collectors"] / base["collectors"])
        e["trainer_vs_first"] = e["updates_per_s"] / base["updates_per_s"]
    _save("collectors", {"step_seconds": args.step_seconds, "runs": out})
    lines = [
        "| collectors | env steps/s | of linear (x the 1-collector rate) | env steps/s of one collector while collecting "
        "| trainer updates/s | trainer vs 1 collector |",
        "|---|---|---|---|---|---|",
    ]
    for e in out:
        lines.append(
            f"| {e['collectors']} | {e['env_steps_per_s']:.1f} | {e['of_linear']:.2f} | {e['per_collector_while_collecting']:.1f} "
            f"| {e['updates_per_s']:.0f} | {e['trainer_vs_first']:.2f} |"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------- updaters on a stand-in machine
def updaters(args: argparse.Namespace, folder: Path) -> str:
    from updater_standin import measure_updaters

    source = folder / "source"
    taskrl.train("pointreach-qtopt-her", out=source, total_steps=5_000, **{**QUIET, "save_replay": True})
    out = []
    for m in args.counts:
        entry = measure_updaters(source, m, args.label_seconds, args.seconds, args.batches_per_call)
        out.append(entry)
        print(json.dumps(entry), flush=True)
    base = out[0]
    for e in out:
        e["of_linear"] = e["targets_per_s"] / (base["targets_per_s"] * e["updaters"] / base["updaters"])
    _save(
        f"updaters_{args.batches_per_call}" if args.batches_per_call > 1 else "updaters",
        {"label_seconds": args.label_seconds, "runs": out},
    )
    lines = [
        f"Batches per updater call: {args.batches_per_call}.",
        "",
        "| updaters | targets/s | of linear (x the 1-updater rate) | of the stand-in's bound (updaters x batch / label time) "
        "| trainer updates/s | mean queue depth |",
        "|---|---|---|---|---|---|",
    ]
    for e in out:
        bound = e["updaters"] * e["batch_size"] / args.label_seconds
        lines.append(
            f"| {e['updaters']} | {e['targets_per_s']:,.0f} | {e['of_linear']:.2f} | {e['targets_per_s'] / bound:.2f} "
            f"| {e['updates_per_s']:.1f} | {e['queue_depth']:.1f} |"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------- FetchPush at a fixed budget
def fetchpush(args: argparse.Namespace, folder: Path) -> str:
    layouts = {
        "in-process, 0.1 updates/env step": {},
        "2 collectors, 1 updater, 0.1": dict(distributed=True, collectors=2, bellman_updaters=1),
        "2 collectors, 1 updater, 0.4": dict(distributed=True, collectors=2, bellman_updaters=1, updates_per_step=0.4),
    }
    out = []
    for name, cluster in layouts.items():
        metrics, rows, wall = _train(
            "fetchpush-qtopt-her",
            folder / name.replace(" ", "_").replace(",", "").replace("/", "_"),
            total_steps=args.steps,
            eval_interval=args.steps // 4,
            eval_episodes=100,
            seed=0,
            **cluster,
        )
        entry = {
            "layout": name,
            "env_steps": rows[-1]["env_steps"],
            "updates": rows[-1]["updates"],
            "success": [r["success_rate"] for r in rows],
            "training_seconds": rows[-1]["wall_seconds"],
            **_window(rows),
        }
        out.append(entry)
        print(json.dumps(entry), flush=True)
    _save("fetchpush", {"steps": args.steps, "runs": out})
    lines = ["| layout | env steps | updates | success at each quarter | training s | env steps/s |", "|---|---|---|---|---|---|"]
    for e in out:
        lines.append(
            f"| {e['layout']} | {e['env_steps']:,} | {e['updates']:,} | {', '.join(f'{s:.2f}' for s in e['success'])} "
            f"| {e['training_seconds']:.0f} | {e['env_steps_per_s']:.0f} |"
        )
    return "\n".join(lines)


# ---------------------------------------------------------------------- per-role costs, and a projection
def costs(args: argparse.Namespace, folder: Path) -> str:
    """Milliseconds of each role's unit of work on one core (FetchReach-v4, the QT-Opt + HER preset), and
    the env steps/s that C collector cores and U updater cores would give a trainer on one core."""
    import torch

    from taskrl.overrides import with_overrides
    from taskrl.presets import preset_config
    from taskrl.run import build

    torch.set_num_threads(1)
    config = with_overrides(preset_config("fetchreach-qtopt-her"), {"num_envs": 1, "threads": 1})
    parts = build(config)
    env, agent, replay = parts.env, parts.agent, parts.replay
    g = torch.Generator().manual_seed(0)
    obs = env.reset(seed=0)
    replay.start(obs)

    def timed(fn, n: int) -> float:
        fn()
        start = time.perf_counter()
        for _ in range(n):
            fn()
        return (time.perf_counter() - start) / n * 1e3

    def collect_step():
        nonlocal obs
        action = agent.act(obs, explore=True, generator=g)
        next_obs, reward, terminated, truncated, info = env.step(action)
        replay.add(action, reward, terminated, truncated, info["final_obs"], next_obs)
        obs = next_obs

    step_ms = timed(collect_step, 2_000)  # also fills the replay
    from taskrl.training.offpolicy import batch_sampler

    sample = batch_sampler(parts.sampler, config.batch_size, parts.generator)
    batch = sample()
    sample_ms = timed(sample, 200)
    target_ms = timed(lambda: agent.bellman_target(batch, g), 50)
    target = agent.bellman_target(batch, g)
    regress_ms = timed(lambda: agent.regress(batch, target), 200)
    parts.close()
    ratio = config.updates_per_step
    entry = {
        "collect_step_ms": step_ms,
        "sample_relabel_ms": sample_ms,
        "bellman_target_ms": target_ms,
        "regress_ms": regress_ms,
        "batch_size": config.batch_size,
        "updates_per_step": ratio,
    }
    _save("costs", entry)
    trainer_updates = 1e3 / (sample_ms + regress_ms)  # the trainer samples for the updaters and regresses
    pipeline = None  # labelled batches/s the trainer process moved with many stand-in updaters (transfers included)
    measured = RESULTS / "distributed_updaters.json"
    if measured.exists():
        pipeline = max(r["updates_per_s"] for r in json.loads(measured.read_text())["runs"])
    lines = [
        f"One core, one torch thread, FetchReach-v4 with the `fetchreach-qtopt-her` preset ((128, 128) Q-network, CEM 64 + 64 "
        f"samples, batch {config.batch_size}, {ratio} updates per env step): a collector's env step with its CEM action "
        f"{step_ms:.2f} ms; the trainer's sample + hindsight relabel {sample_ms:.2f} ms and regression {regress_ms:.2f} ms "
        f"per update; a Bellman updater's CEM target for a batch {target_ms:.1f} ms.",
        "",
        "Projected env steps/s at this update-to-data ratio, with the trainer on one core, C cores of collectors and U "
        "cores of updaters: the smallest of C / step, U / (ratio x target), trainer compute / ratio and, where measured, "
        f"the trainer process's labelled-batch rate with many stand-in updaters ({pipeline or 0:.0f} batches/s, transfers "
        "included; `distributed_updaters.json`) / ratio:",
        "",
        "| collector cores C | updater cores U | env steps/s | limited by |",
        "|---|---|---|---|",
    ]
    for c, u in ((1, 1), (2, 1), (2, 2), (4, 4), (8, 8), (8, 16), (16, 16), (32, 32)):
        bounds = {
            "collectors": c * 1e3 / step_ms,
            "updaters": u * 1e3 / (ratio * target_ms),
            "trainer compute": trainer_updates / ratio,
        }
        if pipeline:
            bounds["trainer process (transfers)"] = pipeline / ratio
        which = min(bounds, key=bounds.get)
        lines.append(f"| {c} | {u} | {bounds[which]:,.0f} | {which} |")
    return "\n".join(lines)


PARTS = {"costs": costs, "fetchreach": fetchreach, "collectors": collectors, "updaters": updaters, "fetchpush": fetchpush}
TITLES = {
    "costs": "Distributed QT-Opt: per-role costs on FetchReach-v4 and what N machines would give",
    "fetchreach": "Distributed QT-Opt + HER on FetchReach-v4: per-role throughput and time to 90%",
    "collectors": "Distributed collection: scaling with sleep-bound collectors (a 50 Hz robot stand-in)",
    "updaters": "Distributed Bellman updaters: scaling with a sleep-bound stand-in",
    "fetchpush": "Distributed QT-Opt + HER on FetchPush-v4 at a fixed budget",
}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("part", choices=sorted(PARTS))
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--steps", type=int, default=4_000)
    parser.add_argument("--counts", type=int, nargs="+", default=[1, 2, 4, 8, 16])
    parser.add_argument("--step-seconds", type=float, default=0.02)
    parser.add_argument("--label-seconds", type=float, default=0.04)
    parser.add_argument("--batches-per-call", type=int, default=1, help="updaters: batches labelled per call")
    parser.add_argument("--seconds", type=float, default=60.0, help="collection seconds per configuration")
    parser.add_argument("--layouts", nargs="+", default=None, help="fetchreach: only these layouts (names as in LAYOUTS)")
    parser.add_argument("--rows-from", default=None, help="fetchreach: JSON lines of runs already made, kept and not rerun")
    parser.add_argument("--write", action="store_true", help="append a section to benchmarks/RESULTS.md")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="taskrl-distributed-"))
    try:
        table = PARTS[args.part](args, folder)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    print(table)
    if args.write:
        append_results(TITLES[args.part], table)


if __name__ == "__main__":
    main()
