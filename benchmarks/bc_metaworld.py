"""Multi-task behaviour cloning on Meta-World from scripted demonstrations: per-task success, wall time, memory.

For each preset and seed: ``taskrl train PRESET --dataset DIR --seed S`` (its own process, so its peak
memory is its own), then ``taskrl eval RUN --episodes 50 --json`` (Meta-World's protocol: 50 distinct
goal positions per task, success at any step of a 500-step episode), then, for presets with held-out
tasks, the held-out evaluation by description, by paraphrase and by one demonstration, with two controls
beside them: a null prompt and another held-out task's description (``taskrl eval RUN --held-out --prompt
...``). Raw results go to ``benchmarks/results/bc_<name>.json`` and a section to RESULTS.md; every figure
is labelled with its protocol (goal observed, or hidden as ML45 hides it: ``--extra=--hidden-goal``).

    .venv/bin/python benchmarks/bc_metaworld.py --presets bc-mt10-onehot bc-mt10-language bc-mt10-demo \
        --dataset data/mt10 --seeds 0 1 --name mt10
    .venv/bin/python benchmarks/bc_metaworld.py --presets bc-ml45-language --dataset data/ml45 --seeds 0 1 2 \
        --train-episodes 10 --name ml45-hidden-goal --extra=--hidden-goal
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import append_results  # noqa: E402
from taskrl.loading import wilson_interval  # noqa: E402

TASKRL = str(Path(sys.executable).with_name("taskrl"))
PROMPTS = ("description", "paraphrase", "demo", "none", "other-task")
PROMPT_TITLES = {
    "description": "description",
    "paraphrase": "paraphrase",
    "demo": "one demonstration",
    "none": "control: null prompt",
    "other-task": "control: another task's description",
}


def pooled(rows: list[dict], task: str | None = None) -> tuple[float, list[float]]:
    """Success over every seed's episodes (of one task, or of all), and its 95% Wilson interval."""
    cells = (
        [(r["per_task"][task], r["episodes"]) for r in rows]
        if task
        else [(r["success_rate"], r["episodes"] * len(r["per_task"])) for r in rows]
    )
    n = sum(e for _, e in cells)
    successes = sum(p * e for p, e in cells)
    return successes / n, wilson_interval(successes, n)


def cell(rate: float, interval: list[float]) -> str:
    return f"{rate:.2f} [{interval[0]:.2f}, {interval[1]:.2f}]"


def run(command: list[str]) -> tuple[str, float, float]:
    """(stdout, wall seconds, peak RSS MiB of this command, read by GNU time)."""
    with tempfile.NamedTemporaryFile("r", suffix=".rss") as rss:
        start = time.perf_counter()
        done = subprocess.run(["/usr/bin/time", "-f", "%M", "-o", rss.name, *command], capture_output=True, text=True)
        seconds = time.perf_counter() - start
        if done.returncode != 0:
            raise SystemExit(f"{' '.join(command)} failed:\n{done.stderr[-3000:]}")
        peak = int(rss.read().strip().splitlines()[-1]) / 1024
    return done.stdout, seconds, peak


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--presets", nargs="+", required=True)
    parser.add_argument("--dataset", required=True)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--episodes", type=int, default=50, help="evaluation episodes per held-out task")
    parser.add_argument("--train-episodes", type=int, default=None, help="per training task (default: --episodes)")
    parser.add_argument("--name", required=True)
    parser.add_argument("--out", default="runs/bench-bc")
    parser.add_argument("--report", default=None, help="only write the section from this raw JSON (runs already made)")
    parser.add_argument(
        "--extra", action="append", default=[], help="one more train flag, e.g. --extra=--total-steps=20000 (repeatable)"
    )
    args = parser.parse_args()
    card = json.loads(
        subprocess.run([TASKRL, "demos", "info", args.dataset, "--json"], capture_output=True, text=True, check=True).stdout
    )
    raw = Path(f"benchmarks/results/bc_{args.name}.json")
    results = json.loads(Path(args.report).read_text()) if args.report else []
    for preset in [] if args.report else args.presets:
        for seed in args.seeds:
            run_dir = Path(args.out) / f"{preset}-seed{seed}"
            if run_dir.exists():
                raise SystemExit(f"{run_dir} exists; remove it or choose another --out")
            train_out, train_s, train_mib = run(
                [
                    TASKRL,
                    "train",
                    preset,
                    "--dataset",
                    args.dataset,
                    "--seed",
                    str(seed),
                    "--out",
                    str(run_dir),
                    "--no-progress",
                    *args.extra,
                ]
            )
            metrics = json.loads(train_out.strip().splitlines()[-1])
            train_episodes = args.train_episodes or args.episodes
            eval_out, eval_s, _ = run([TASKRL, "eval", str(run_dir), "--episodes", str(train_episodes), "--json"])
            result = json.loads(eval_out)
            entry = {
                "preset": preset,
                "seed": seed,
                "train_seconds": round(train_s, 1),
                "training_wall_seconds": metrics["wall_seconds"],
                "updates": metrics["updates"],
                "train_peak_mib": round(train_mib),
                "eval_seconds": round(eval_s, 1),
                "episodes": train_episodes,
                "success_rate": result["success_rate"],
                "per_task": {k: v["success_rate"] for k, v in result["tasks"].items()},
            }
            config = json.loads((run_dir / "config.json").read_text())
            entry["hidden_goal"] = bool(config.get("metaworld", {}).get("hidden_goal", False))
            if config.get("env") == "ml45":
                for prompt in PROMPTS:
                    out, seconds, _ = run(
                        [TASKRL, "eval", str(run_dir), "--held-out", "--prompt", prompt, "--dataset", args.dataset]
                        + ["--episodes", str(args.episodes), "--json"]
                    )
                    held = json.loads(out)
                    entry[f"held_out_{prompt}"] = {
                        "episodes": args.episodes,
                        "success_rate": held["success_rate"],
                        "per_task": {k: v["success_rate"] for k, v in held["tasks"].items()},
                        "seconds": round(seconds, 1),
                    }
            results.append(entry)
            print(json.dumps(entry), flush=True)
            raw.parent.mkdir(exist_ok=True)
            raw.write_text(json.dumps(results, indent=2) + "\n")  # after every run: a stopped benchmark keeps its runs
    raw.parent.mkdir(exist_ok=True)
    raw.write_text(json.dumps(results, indent=2) + "\n")
    info = card.get("card", {})
    protocols = sorted(
        {"goal hidden (ML45's protocol)" if r.get("hidden_goal") else "goal observed (MT protocol)" for r in results}
    )
    lines = [
        f"Protocol: {', '.join(protocols)}.",
        "",
        f"Dataset `{args.dataset}`: {card['total_episodes']:,} episodes, {card['total_steps']:,} steps, "
        f"{card.get('dataset_size', '?')} MB, made by `taskrl demos collect {info.get('source')}` with noise "
        f"{info.get('noise_std')} and {info.get('after_success', 0)} steps after success in "
        f"{info.get('collection_seconds', '?')} s. {results[0].get('episodes', args.episodes)} evaluation episodes per "
        f"training task and {args.episodes} per held-out task (distinct goal positions, success at any step of 500); "
        "each preset's own settings"
        + (f" with `{' '.join(args.extra)}`" if args.extra else "")
        + f". Intervals: 95% Wilson over every seed's episodes together. Raw: `benchmarks/results/bc_{args.name}.json`.",
        "",
        "| preset | seeds | success (mean over tasks), per seed | all seeds [95% interval] | training s: updates only (whole command) | peak MiB |",
        "|---|---|---|---|---|---|",
    ]

    def seconds(r: dict) -> str:
        return f"{r['training_wall_seconds']:.0f} ({r['train_seconds']:.0f})"

    for preset in args.presets:
        rows = [r for r in results if r["preset"] == preset]
        per_seed = ", ".join(f"{r['success_rate']:.3f}" for r in rows)
        for r in rows:
            r.setdefault("episodes", args.episodes)
        lines.append(
            f"| {preset} | {len(rows)} | {per_seed} | {cell(*pooled(rows))} | "
            f"{', '.join(seconds(r) for r in rows)} | "
            f"{max(r['train_peak_mib'] for r in rows)} |"
        )
    tasks = list(results[0]["per_task"])
    lines += [
        "",
        "Per task (mean over seeds):",
        "",
        "| task | " + " | ".join(args.presets) + " |",
        "|---" * (len(args.presets) + 1) + "|",
    ]
    for task in tasks:
        cells = [f"{statistics.fmean(r['per_task'][task] for r in results if r['preset'] == p):.2f}" for p in args.presets]
        lines.append(f"| {task} | " + " | ".join(cells) + " |")
    held = [r for r in results if "held_out_none" in r]
    if held:
        prompts = [p for p in PROMPTS if all(f"held_out_{p}" in r for r in held)]
        lines += [
            "",
            f"Held-out tasks, zero-shot, {len(held)} seeds pooled: success [95% interval]. The controls say what the "
            "policy does on these tasks without being told them; the prompt's part is the gain over the better control.",
            "",
            "| task | " + " | ".join(PROMPT_TITLES[p] for p in prompts) + " |",
            "|---" * (len(prompts) + 1) + "|",
        ]
        for task in held[0]["held_out_description"]["per_task"]:
            cells = [cell(*pooled([r[f"held_out_{p}"] for r in held], task)) for p in prompts]
            lines.append(f"| {task} | " + " | ".join(cells) + " |")
        means = {p: pooled([r[f"held_out_{p}"] for r in held]) for p in prompts}
        lines.append("| **all** | " + " | ".join(f"**{cell(*means[p])}**" for p in prompts) + " |")
        control = max(("none", "other-task"), key=lambda p: means[p][0])
        per_seed = [
            r["held_out_description"]["success_rate"]
            - max(r["held_out_none"]["success_rate"], r["held_out_other-task"]["success_rate"])
            for r in held
        ]
        lines += [
            "",
            f"Gain of the description over the better control ({PROMPT_TITLES[control]}): "
            f"{means['description'][0] - means[control][0]:+.3f} pooled; per seed (against that seed's better control) "
            + ", ".join(f"{g:+.3f}" for g in per_seed)
            + ".",
        ]
    append_results(f"Multi-task behaviour cloning: {args.name}", "\n".join(lines))


if __name__ == "__main__":
    main()
