"""HG-DAgger against plain behaviour cloning at equal expert-labelled steps (Meta-World MT10 by default).

For each seed:

1. ``base``: ``taskrl demos collect mt10 --episodes B --noise 0.1`` (the first demonstrations) and ``pool``: more
   demonstrations of the same kind, from another seed (plain BC's extra labels);
2. HG-DAgger: train the preset on ``base``; then ``R`` rounds of ``taskrl demos dagger`` (E episodes per task, the
   scripted expert taking over under the default intervention rule), ``taskrl demos merge`` of everything so far,
   and training afresh on the aggregate (DAgger retrains on the aggregate every round);
3. plain BC: ``taskrl demos merge base pool --max-steps N``, N the expert-labelled steps of HG-DAgger's final
   aggregate, and training on it;
4. every policy evaluated by Meta-World's protocol (distinct goal positions, success at any step).

    .venv/bin/python benchmarks/hg_dagger.py --seeds 0 1 2 --write

Raw rows go to ``benchmarks/results/hg_dagger.json`` after every seed.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
import taskrl  # noqa: E402
from common import append_results  # noqa: E402
from taskrl.demos.collect import collect_demos  # noqa: E402
from taskrl.demos.dagger import InterventionRule, collect_interventions, merge_datasets  # noqa: E402
from taskrl.demos.dataset import read_episodes  # noqa: E402
from taskrl.loading import load_run, wilson_interval  # noqa: E402

RAW = HERE / "results" / "hg_dagger.json"


def steps(folder: Path) -> int:
    return sum(len(e) for e in read_episodes(folder))


def train(args: argparse.Namespace, dataset: Path, out: Path, seed: int) -> dict:
    started = time.perf_counter()
    taskrl.train(
        args.preset,
        out=out,
        dataset=str(dataset),
        seed=seed,
        threads=1,
        tensorboard=False,
        eval_interval=10**9,
        eval_episodes=1,
        progress=False,
    )
    result = taskrl.evaluate_run(out, episodes=args.eval_episodes)
    return {
        "success_rate": result["success_rate"],
        "per_task": {k: v["success_rate"] for k, v in result["tasks"].items()},
        "seconds": round(time.perf_counter() - started, 1),
    }


def one_seed(args: argparse.Namespace, seed: int, folder: Path) -> dict:
    base, pool = folder / "base", folder / "pool"
    collect_demos(args.source, args.base_episodes, base, seed=100 + seed, noise_std=args.noise)
    collect_demos(args.source, args.pool_episodes, pool, seed=200 + seed, noise_std=args.noise)
    row: dict = {"seed": seed, "base_steps": steps(base)}
    row["bc_base"] = train(args, base, folder / "run0", seed)
    print(json.dumps({"seed": seed, "bc_base": row["bc_base"]["success_rate"]}), flush=True)
    parts, rounds = [base], []
    for r in range(1, args.rounds + 1):
        corrections = folder / f"corrections{r}"
        card = collect_interventions(
            load_run(folder / f"run{r - 1}"),
            corrections,
            episodes=args.dagger_episodes,
            rule=InterventionRule(),
            seed=300 + 10 * r + seed,
        )
        if (corrections / "data").exists():
            parts.append(corrections)
        merge_datasets(parts, folder / f"aggregate{r}")
        result = train(args, folder / f"aggregate{r}", folder / f"run{r}", seed)
        rounds.append(
            {
                "round": r,
                "expert_steps": card["expert_steps_total"],
                "policy_steps": card["policy_steps_total"],
                "interventions": sum(card["interventions"].values()),
                "success_with_interventions": statistics.fmean(card["success_rate_with_interventions"].values()),
                "labelled_steps": steps(folder / f"aggregate{r}"),
                **result,
            }
        )
        print(json.dumps({"seed": seed, **{k: v for k, v in rounds[-1].items() if k != "per_task"}}), flush=True)
    row["rounds"] = rounds
    labelled = rounds[-1]["labelled_steps"] if rounds else row["base_steps"]
    if steps(base) + steps(pool) < labelled:
        raise SystemExit(
            f"seed {seed}: the pool holds too few demonstrations for {labelled} labelled steps: raise --pool-episodes"
        )
    merge_datasets([base, pool], folder / "equal", max_steps=labelled)
    row["bc_equal_labels"] = {"labelled_steps": steps(folder / "equal"), **train(args, folder / "equal", folder / "bc", seed)}
    print(json.dumps({"seed": seed, "bc_equal": row["bc_equal_labels"]["success_rate"]}), flush=True)
    return row


def report(args: argparse.Namespace, rows: list[dict]) -> str:
    episodes = args.eval_episodes * len(rows[0]["bc_base"]["per_task"])

    def pooled(rates: list[float]) -> str:
        n = episodes * len(rates)
        low, high = wilson_interval(sum(r * episodes for r in rates), n)
        return f"{statistics.fmean(rates):.3f} [{low:.3f}, {high:.3f}]"

    hg = [r["rounds"][-1]["success_rate"] for r in rows]
    bc = [r["bc_equal_labels"]["success_rate"] for r in rows]
    lines = [
        f"Preset `{args.preset}` on `{args.source}`; first demonstrations: {args.base_episodes} per task (noise "
        f"{args.noise}); HG-DAgger: {args.rounds} rounds of {args.dagger_episodes} episodes per task under the default "
        f"intervention rule ({InterventionRule()}), retrained afresh on the aggregate each round; plain BC: the first "
        "demonstrations plus more of the same kind, cut to HG-DAgger's final number of expert-labelled steps. "
        f"Evaluation: {args.eval_episodes} episodes per task (Meta-World: distinct goal positions, success at any step). Intervals: 95% Wilson over every "
        "seed's episodes together. Raw: `benchmarks/results/hg_dagger.json`.",
        "",
        "| seed | expert-labelled steps: first demos / + corrections | BC on the first demos | HG-DAgger | BC at equal labels "
        "| HG-DAgger − BC |",
        "|---|---|---|---|---|---|",
    ]
    for r, h, b in zip(rows, hg, bc):
        lines.append(
            f"| {r['seed']} | {r['base_steps']:,} / {r['rounds'][-1]['labelled_steps']:,} | {r['bc_base']['success_rate']:.3f} "
            f"| {h:.3f} | {b:.3f} | {h - b:+.3f} |"
        )
    lines.append(
        f"| **all** | | {pooled([r['bc_base']['success_rate'] for r in rows])} | {pooled(hg)} | {pooled(bc)} "
        f"| {statistics.fmean(hg) - statistics.fmean(bc):+.3f} |"
    )
    lines += [
        "",
        "Per round (mean over seeds):",
        "",
        "| round | expert steps / policy steps while collecting | interventions "
        "| success with interventions | labelled steps | success after retraining |",
        "|---|---|---|---|---|---|",
    ]
    for i in range(args.rounds):
        at = [r["rounds"][i] for r in rows]
        lines.append(
            f"| {i + 1} | {statistics.fmean(a['expert_steps'] for a in at):,.0f} / {statistics.fmean(a['policy_steps'] for a in at):,.0f} "
            f"| {statistics.fmean(a['interventions'] for a in at):.0f} | {statistics.fmean(a['success_with_interventions'] for a in at):.3f} "
            f"| {statistics.fmean(a['labelled_steps'] for a in at):,.0f} | {statistics.fmean(a['success_rate'] for a in at):.3f} |"
        )
    tasks = list(rows[0]["bc_base"]["per_task"])
    lines += [
        "",
        "Per task (mean over seeds):",
        "",
        "| task | BC on the first demos | HG-DAgger | BC at equal labels |",
        "|---|---|---|---|",
    ]
    for t in tasks:
        cells = [
            statistics.fmean(r["bc_base"]["per_task"][t] for r in rows),
            statistics.fmean(r["rounds"][-1]["per_task"][t] for r in rows),
            statistics.fmean(r["bc_equal_labels"]["per_task"][t] for r in rows),
        ]
        lines.append(f"| {t} | " + " | ".join(f"{c:.2f}" for c in cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--preset", default="bc-mt10-onehot")
    parser.add_argument("--source", default="mt10")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--base-episodes", type=int, default=10)
    parser.add_argument("--pool-episodes", type=int, default=30)
    parser.add_argument("--noise", type=float, default=0.1)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--dagger-episodes", type=int, default=5)
    parser.add_argument("--eval-episodes", type=int, default=20)
    parser.add_argument("--out", default="runs/bench-hg-dagger")
    parser.add_argument("--report", action="store_true", help="only write the section from the raw JSON")
    parser.add_argument("--write", action="store_true", help="write the section to benchmarks/RESULTS.md")
    args = parser.parse_args()
    rows = json.loads(RAW.read_text())["rows"] if args.report else []
    for seed in [] if args.report else args.seeds:
        folder = Path(args.out) / f"seed{seed}"
        if folder.exists():
            raise SystemExit(f"{folder} exists; remove it or choose another --out")
        rows.append(one_seed(args, seed, folder))
        RAW.parent.mkdir(exist_ok=True)
        RAW.write_text(json.dumps({"args": vars(args), "rows": rows}, indent=1) + "\n")
    table = report(args, rows)
    print(table)
    if args.write:
        append_results("Multi-task imitation: HG-DAgger against BC at equal expert labels", table)


if __name__ == "__main__":
    main()
