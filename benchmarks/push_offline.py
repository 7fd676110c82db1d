"""FetchPush: each learner on each learner's data, offline. Which one stands in QT-Opt's way, its learner or its data?

Online, SAC + HER with QT-Opt's network and update ratio pushes (0.9 at about 550k env steps) and QT-Opt + HER does
not (0.07 at 1M); both start from alike data (RESULTS, "FetchPush: how often each learner's own episodes moved the
block"). Here each learner trains ``--offline`` (no env step, hindsight relabelling as online) on the stored replay of
an online run: SAC's, which holds pushes that succeed, and QT-Opt's, which does not. A learner that pushes from SAC's
data but not from its own has a data problem (its exploration); one that fails on SAC's data too has a learner
problem. Arms (``LEARNERS``): QT-Opt with the Huber loss (its defaults before the squared loss), the same with the
2 x 64 target search, QT-Opt's defaults (the squared loss), SAC with QT-Opt's network.

    .venv/bin/python benchmarks/push_offline.py --data sac=RUN qtopt=RUN --learners qtopt sac --updates 40000 --write
"""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent
HUBER = {"loss": "huber"}  # QT-Opt's loss on the goal envs until the squared loss replaced it
LEARNERS = {
    "qtopt": ("QT-Opt with the Huber loss (`fetchpush-qtopt-her` before the squared loss)", "fetchpush-qtopt-her", HUBER),
    "qtopt-2x64": (
        "QT-Opt with the Huber loss and the 2 x 64 target search",
        "fetchpush-qtopt-her",
        {**HUBER, "target_samples": 64, "target_iterations": 2, "target_elites": 6},
    ),
    "qtopt-mse": ("QT-Opt's defaults (`fetchpush-qtopt-her`): the squared loss", "fetchpush-qtopt-her", {"loss": "mse"}),
    "sac": (
        "SAC + HER with QT-Opt's network (`fetchpush-sac-her`, 128 x 128)",
        "fetchpush-sac-her",
        {"hidden_sizes": (128, 128)},
    ),
}
DIAGNOSTICS = ("q_spread", "twin_clip_rate")


def train_offline(learner: str, data_name: str, data: str, updates: int, eval_interval: int, root: str, seed: int) -> str:
    import torch

    import taskrl

    torch.set_num_threads(1)
    _, preset, settings = LEARNERS[learner]
    out = Path(root) / f"{learner}-on-{data_name}-s{seed}"
    common = {"total_steps": updates, "tensorboard": False, "threads": 1}
    if (out / "checkpoints").exists():
        taskrl.train(resume=out, **common)
    else:
        taskrl.train(
            preset, out=out, seed=seed, offline=True, offline_data=data, eval_interval=eval_interval, **settings, **common,
        )  # fmt: skip
    return str(out)


def summarise(run_dir: Path, marks: list[int]) -> dict:
    from taskrl.logger import read_metrics

    rows = [r for r in read_metrics(run_dir / "metrics.csv") if r["success_rate"] is not None]

    def at(mark: int) -> dict | None:
        return next((r for r in rows if r["updates"] >= mark), None)

    return {
        "run": run_dir.name,
        "updates": rows[-1]["updates"],
        "hours": rows[-1]["wall_seconds"] / 3600,
        "best_success": max(r["success_rate"] for r in rows),
        "marks": {m: {k: at(m).get(k) for k in ("success_rate", *DIAGNOSTICS)} if at(m) else None for m in marks},
        "curve": [(r["updates"], r["success_rate"]) for r in rows],
    }


def table(results: list[dict], marks: list[int]) -> str:
    head = " / ".join(f"{m // 1000}k" for m in marks)

    def cells(r: dict, key: str, digits: int) -> str:
        return " / ".join(
            f"{r['marks'][m][key]:.{digits}f}" if r["marks"][m] and r["marks"][m][key] is not None else "-" for m in marks
        )

    lines = [
        f"| learner | data | updates | hours | success at {head} updates | best | Q spread | twin clips |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        learner, _, data = r["run"].rpartition("-s")[0].partition("-on-")
        qtopt = learner.startswith("qtopt")
        lines.append(
            f"| {LEARNERS[learner][0]} | {data}'s replay | {r['updates']:,} | {r['hours']:.2f} | {cells(r, 'success_rate', 2)} "
            f"| {r['best_success']:.2f} | {cells(r, 'q_spread', 3) if qtopt else '-'} | {cells(r, 'twin_clip_rate', 2) if qtopt else '-'} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", nargs="+", required=True, metavar="NAME=RUN", help="online runs whose replay is the data")
    parser.add_argument("--learners", nargs="+", default=["qtopt", "sac"], choices=list(LEARNERS))
    parser.add_argument("--updates", type=int, default=40_000)
    parser.add_argument("--eval-interval", type=int, default=5_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=HERE / "out" / "push_offline")
    parser.add_argument("--report", action="store_true", help="train nothing; report the runs as they stand")
    parser.add_argument("--note", default="")
    parser.add_argument("--write", action="store_true")
    args = parser.parse_args()
    data = dict(spec.split("=", 1) for spec in args.data)
    runs = [(learner, name) for name in data for learner in args.learners]
    args.out.mkdir(parents=True, exist_ok=True)
    if not args.report:
        with ProcessPoolExecutor(args.workers) as pool:
            jobs = [
                pool.submit(train_offline, learner, name, data[name], args.updates, args.eval_interval, str(args.out), args.seed)
                for learner, name in runs
            ]
            for job in jobs:
                job.result()
    marks = [m for m in (5_000, 10_000, 20_000, 40_000, 80_000) if m <= args.updates]
    present = [
        args.out / f"{lr}-on-{n}-s{args.seed}"
        for lr, n in runs
        if (args.out / f"{lr}-on-{n}-s{args.seed}" / "metrics.csv").exists()
    ]
    results = [summarise(p, marks) for p in present]
    text = table(results, marks)
    print(text)
    if args.write:
        from common import append_results

        (HERE / "results" / "push_offline.json").write_text(json.dumps({"data": data, "runs": results}, indent=1) + "\n")
        sources = "; ".join(f"{name}: `{run}`" for name, run in data.items())
        append_results(
            "FetchPush: each learner offline on each learner's data",
            f"`--offline --offline-data RUN` (no env step; hindsight relabelling as online), seed {args.seed}, one torch "
            f"thread per run, {args.workers} at a time; greedy success over 100 evaluation episodes every "
            f"{args.eval_interval:,} updates. The data ({sources}) are the stored replays of the online runs of "
            f"'QT-Opt + HER learning to push (fetchpush)'. {args.note} Raw data: `benchmarks/results/push_offline.json`."
            f"\n\n{text}",
        )


if __name__ == "__main__":
    main()
