"""BC-Z from pixels on the tabletop: success against demonstrations per task, and zero-shot held-out combinations.

For each number of demonstrations per task N (``--demos``) the scripted experts' dataset is collected
(``taskrl demos collect tabletop --episodes N --noise 0.2``, all nine tasks; the run trains on the six training tasks),
then for every seed ``taskrl train bc-tabletop-language --dataset DIR --seed S``, the training tasks'
evaluation (``taskrl eval RUN --episodes E``) and the three held-out verb-colour combinations zero-shot,
prompted by their description, a paraphrase and the two controls (a null prompt, another held-out task's
description): ``taskrl eval RUN --held-out --prompt P``. Raw results: ``benchmarks/results/bc_tabletop_NAME.json``;
a section in RESULTS.md and a figure, ``benchmarks/figures/bc_tabletop.png``.

    .venv/bin/python benchmarks/bc_tabletop.py --demos 10 25 100 --seeds 0 1 2
    .venv/bin/python benchmarks/bc_tabletop.py --report benchmarks/results/bc_tabletop_main.json   # the section again
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from bc_metaworld import PROMPT_TITLES, TASKRL, cell, pooled, run  # noqa: E402
from common import append_results  # noqa: E402

PROMPTS = ("description", "paraphrase", "none", "other-task")  # pictures: no demonstration prompts
PRESET = "bc-tabletop-language"
NOISE = 0.2  # DART: the executed action noisy, the label the expert's (0.2 took one seed from 0.56 to 0.89 at 5k updates)
FIGURE = Path("benchmarks/figures/bc_tabletop.png")


def dataset(root: Path, demos: int) -> Path:
    out = root / f"tabletop-{demos}"
    if not (out / "data").exists():
        command = [TASKRL, "demos", "collect", "tabletop", "--episodes", str(demos), "--noise", str(NOISE), "--out", str(out)]
        subprocess.run(command, check=True, capture_output=True)
    return out


def one_run(args, demos: int, seed: int) -> dict:
    data = dataset(Path(args.data), demos)
    run_dir = Path(args.out) / f"demos{demos}-seed{seed}"
    if run_dir.exists():
        raise SystemExit(f"{run_dir} exists; remove it or choose another --out")
    train = [TASKRL, "train", PRESET, "--dataset", str(data), "--seed", str(seed), "--out", str(run_dir), "--no-progress"]
    train_out, train_s, train_mib = run([*train, *args.extra])
    metrics = json.loads(train_out.strip().splitlines()[-1])
    result = json.loads(run([TASKRL, "eval", str(run_dir), "--episodes", str(args.episodes), "--json"])[0])
    entry = {
        "demos_per_task": demos,
        "seed": seed,
        "episodes": args.episodes,
        "updates": metrics["updates"],
        "training_wall_seconds": metrics["wall_seconds"],
        "train_seconds": round(train_s, 1),
        "train_peak_mib": round(train_mib),
        "success_rate": result["success_rate"],
        "per_task": {k: v["success_rate"] for k, v in result["tasks"].items()},
    }
    for prompt in PROMPTS:
        held = json.loads(
            run([TASKRL, "eval", str(run_dir), "--held-out", "--prompt", prompt, "--episodes", str(args.episodes), "--json"])[0]
        )
        entry[f"held_out_{prompt}"] = {
            "episodes": args.episodes,
            "success_rate": held["success_rate"],
            "per_task": {k: v["success_rate"] for k, v in held["tasks"].items()},
        }
    return entry


def figure(results: list[dict], demos: list[int]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    lines = {"training tasks": lambda rows: pooled(rows)}
    for prompt in PROMPTS:
        lines[f"held out: {PROMPT_TITLES[prompt]}"] = lambda rows, p=prompt: pooled([r[f"held_out_{p}"] for r in rows])
    for label, stat in lines.items():
        points = [(n, *stat([r for r in results if r["demos_per_task"] == n])) for n in demos]
        xs, ys = [p[0] for p in points], [p[1] for p in points]
        low, high = [p[1] - p[2][0] for p in points], [p[2][1] - p[1] for p in points]
        ax.errorbar(xs, ys, yerr=[low, high], marker="o", capsize=3, label=label)
    ax.set_xscale("log")
    ax.set_xticks(demos, [str(n) for n in demos])
    ax.set_xlabel("demonstrations per task")
    ax.set_ylabel("success (seeds pooled, 95% interval)")
    ax.set_ylim(0, 1.02)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title("BC-Z from 32x32 pictures on the tabletop")
    FIGURE.parent.mkdir(exist_ok=True)
    fig.tight_layout()
    fig.savefig(FIGURE, dpi=120)


def report(results: list[dict], args) -> None:
    demos = sorted({r["demos_per_task"] for r in results})
    figure(results, demos)
    seeds = sorted({r["seed"] for r in results})
    first = results[0]
    lines = [
        f"Preset `{PRESET}` (each run its own process, one torch thread{', with `' + ' '.join(args.extra) + '`' if args.extra else ''}; "
        "the other core ran other benchmarks): "
        f"{first['updates']:,} updates per run, seeds {seeds}. Datasets: `taskrl demos collect tabletop --episodes N "
        f"--noise {NOISE}` (seed 1; DART: noisy actions run, the expert's labelled). Evaluation: "
        f"{first['episodes']} episodes per task, success at any step of 50 (episodes end at success); "
        "intervals: 95% Wilson over every seed's episodes together. Raw: `benchmarks/results/bc_tabletop_*.json`; "
        f"figure: `{FIGURE}`.",
        "",
        "| demos per task | training tasks, per seed | training tasks [95%] | held out: description | paraphrase | "
        "control: null prompt | control: another task's description | gain over the better control |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for n in demos:
        rows = [r for r in results if r["demos_per_task"] == n]
        means = {p: pooled([r[f"held_out_{p}"] for r in rows]) for p in PROMPTS}
        control = max(means["none"][0], means["other-task"][0])
        lines.append(
            f"| {n} | {', '.join(format(r['success_rate'], '.2f') for r in rows)} | {cell(*pooled(rows))} | "
            + " | ".join(cell(*means[p]) for p in PROMPTS)
            + f" | {means['description'][0] - control:+.3f} |"
        )
    top = [r for r in results if r["demos_per_task"] == demos[-1]]
    lines += ["", f"Per task at {demos[-1]} demonstrations per task, seeds pooled:", ""]
    lines += ["| task | success [95%] |", "|---|---|"]
    for task in top[0]["per_task"]:
        lines.append(f"| {task} | {cell(*pooled(top, task))} |")
    for task in top[0]["held_out_description"]["per_task"]:
        cells = [cell(*pooled([r[f"held_out_{p}"] for r in top], task)) for p in PROMPTS]
        lines.append(f"| {task} (held out; description / paraphrase / null / other) | {' / '.join(cells)} |")
    seconds = [r["training_wall_seconds"] for r in results]
    lines += [
        "",
        f"Training time per run: {min(seconds):.0f}-{max(seconds):.0f} s of updates; peak memory "
        f"{max(r['train_peak_mib'] for r in results)} MiB.",
    ]
    append_results("Multi-task behaviour cloning from pixels: tabletop", "\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--demos", nargs="+", type=int, default=[10, 25, 100])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--episodes", type=int, default=50, help="evaluation episodes per task")
    parser.add_argument("--data", default="data", help="where the datasets tabletop-N are made")
    parser.add_argument("--out", default="runs/bench-bc-tabletop")
    parser.add_argument("--name", default="main", help="raw results go to benchmarks/results/bc_tabletop_NAME.json")
    parser.add_argument("--report", nargs="+", default=None, help="only write the section from these raw JSON files")
    parser.add_argument("--extra", action="append", default=[], help="one more train flag (repeatable)")
    args = parser.parse_args()
    raw = Path(f"benchmarks/results/bc_tabletop_{args.name}.json")
    results = [r for path in args.report or [] for r in json.loads(Path(path).read_text())]
    for demos in [] if args.report else args.demos:
        for seed in args.seeds:
            results.append(one_run(args, demos, seed))
            print(json.dumps(results[-1]), flush=True)
            raw.parent.mkdir(exist_ok=True)
            raw.write_text(json.dumps(results, indent=2) + "\n")  # after every run: a stopped benchmark keeps its runs
    report(results, args)


if __name__ == "__main__":
    main()
