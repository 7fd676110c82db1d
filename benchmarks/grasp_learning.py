"""QT-Opt grasping from the camera: the preset against changes to it, per-evaluation curves.

Arms: the preset; scripted exploration (a share of training episodes acted by the env's scripted grasp); a looser
hold (``--env.tolerance 0.06``: the gripper's centre may be 0.06 off an object's spine, about 4 pixels), the positive
control of the bin as it was (tolerance 0.025, squares of half-side 0.035-0.05); 0.06 is the fair bin's default since,
so on today's bin this arm is the preset; "fair bin": the preset on today's bin with the flat join (``--fusion flat
--no-shift-coordinates``, the preset's network until the glimpse's hour), beside "independent twins" (the fair bin's
preset before lagged twins and scripted exploration), each run then evaluated by ``taskrl eval RUN`` and ``taskrl eval
RUN --held-out``; "independent twins", "lagged twins" and "lagged twins + scripted" for half an hour, the two changes
one at a time (runs longer than the budget are read up to it); "glimpse": ``--fusion glimpse --shift-coordinates``
(the whole picture's features beside those of the picture around the gripper in the jaws' frame, today's preset),
compared with the flat join at equal env steps (``--at``) as well as at the end; "glimpse adam 1e-3" (the
preset at 0.25 updates per step) and "two threads" (``--threads 2``: the preset on both cores, one run at a time, as the issue's hour on 2 cores
allows); "half the updates per step" (``--updates-per-step 0.125``, today's preset) against "0.25 updates per step" (the
preset's until then: about twice the env steps for the same updates), and "0.0625 updates per step" against 0.125; "96-pixel pictures" (``--env.image-size 96``) and "less
random exploration" (random actions decayed from 0.3 to 0.05 over 150k env steps) against the preset, the two levers
on the squares' yaw, and "the paper's bellman maximum" (the target's maximum over 2 CEM rounds of 64 candidates
refit to 6 elites, QT-Opt's, instead of one round of 32). Each
arm is reported beside the success of uniformly random actions at its own tolerance. The runs of each
section used the preset of its commit: the arms' flags name what differs from today's.

Each arm is ``taskrl train grasp-qtopt-pixels --seed S --threads 1 --max-hours H`` plus its flags (an arm's
``--threads`` replaces the 1), its own process; a run directory that already holds a finished run (its
``learning_curve.png``) is read instead of trained again, so runs made by hand with these commands count. Evaluation is the greedy policy alone (100 attempts on the training
objects); ``train success`` counts every training attempt, scripted ones included.

    .venv/bin/python benchmarks/grasp_learning.py --seeds 0 --max-hours 0.75 --out /work/runs-bench/grasp --write
    .venv/bin/python benchmarks/grasp_learning.py --arms "looser hold" --seeds 0 --max-hours 1 --out /work/runs-bench/grasp --write
    .venv/bin/python benchmarks/grasp_learning.py --arms "fair bin:0,1,2" "independent twins:0,1" "adam 1e-3:2" \
        --max-hours 1 --out /work/runs-bench/grasp --write
    .venv/bin/python benchmarks/grasp_learning.py --arms "independent twins" "lagged twins" "lagged twins + scripted" \
        --seeds 0 --max-hours 0.5 --out /work/runs-bench/grasp --write
    .venv/bin/python benchmarks/grasp_learning.py --arms "fair bin:0" "glimpse:0,1,2" --max-hours 1.0 \
        --at 25000 50000 90000 --out /work/runs-bench/grasp --write
    .venv/bin/python benchmarks/grasp_learning.py --arms "glimpse:0,1,2" "glimpse adam 1e-3:0,1,2" --max-hours 1.0 \
        --at 25000 50000 90000 --out /work/runs-bench/grasp --write
    .venv/bin/python benchmarks/grasp_learning.py --arms "glimpse adam 1e-3:0,1,2" "two threads:0" --max-hours 1.0 \
        --at 25000 50000 90000 --out /work/runs-bench/grasp --write
    .venv/bin/python benchmarks/grasp_learning.py --arms "0.25 updates per step:0" "half the updates per step:0,1,2" \
        --max-hours 1.0 --at 25000 50000 90000 140000 --at-updates 5000 10000 20000 30000 --out /work/runs-bench/grasp \
        --write
    .venv/bin/python benchmarks/grasp_learning.py --arms "half the updates per step:0,1,2" "0.0625 updates per step:0" \
        --max-hours 1.0 --at 25000 50000 90000 140000 200000 --at-updates 5000 10000 15000 \
        --out /work/runs-bench/grasp --write
    .venv/bin/python benchmarks/grasp_learning.py --arms "half the updates per step:0,1,2" "96-pixel pictures:0" \
        "less random exploration:0" --max-hours 1.0 --at 25000 50000 90000 140000 --out /work/runs-bench/grasp --write
"""

from __future__ import annotations

import argparse
import csv
import functools
import json
import math
import re
import shlex
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import append_results  # noqa: E402
from grasp_random import random_success  # noqa: E402
from taskrl.envs.grasp import GraspSettings  # noqa: E402
from taskrl.presets import PRESETS  # noqa: E402

TASKRL = str(Path(sys.executable).with_name("taskrl"))
PRESET = "grasp-qtopt-pixels"
BATCH = PRESETS[PRESET].overrides["batch_size"]
FLAT = "--fusion flat --no-shift-coordinates"  # the flat join, the preset's network until the glimpse's hour
ADAM_3E4 = "--lr 3e-4"  # the preset's rate until the glimpse at 1e-3 was measured: the arms run before keep it
RATIO_025 = "--updates-per-step 0.25"  # the preset's ratio until 0.125 was measured: the arms run before keep it
ARMS = {
    "preset": "",
    "scripted exploration": "--scripted-exploration 0.5 --scripted-steps 60000",
    "looser hold": "--env.tolerance 0.06",
    "fair bin": f"{FLAT} {ADAM_3E4} {RATIO_025}",  # the preset on today's bin (tolerance 0.06, the sizes at which yaw matters) with the flat join
    # the fair bin's preset until the twins measurement (two online networks), and the two changes measured against it
    "independent twins": f"{FLAT} {ADAM_3E4} {RATIO_025} --algo.twin independent --scripted-exploration 0",
    "lagged twins": f"{FLAT} {ADAM_3E4} {RATIO_025} --algo.twin lagged --scripted-exploration 0",
    "lagged twins + scripted": f"{FLAT} {ADAM_3E4} {RATIO_025} --algo.twin lagged --scripted-exploration 0.5 --scripted-steps 60000",
    # the rate of the benchmark's own config (kukagrasp-qtopt's) on the fair bin's preset: the same cost per update
    "adam 1e-3": f"{FLAT} --lr 1e-3 {RATIO_025}",
    # the whole picture's features beside a glimpse around the gripper in the jaws' frame (the pose moved with the
    # shift): the preset's network since its hour
    "glimpse": f"--fusion glimpse --shift-coordinates {ADAM_3E4} {RATIO_025}",
    # the glimpse at the benchmark's own Adam rate (kukagrasp-qtopt's): the same cost per update, more learning per update?
    "glimpse adam 1e-3": f"--fusion glimpse --shift-coordinates --lr 1e-3 {RATIO_025}",
    # the preset (the glimpse at 1e-3) with two torch threads: one run on both cores, as the hour allows
    "two threads": f"--threads 2 {RATIO_025}",
    # the preset's ratio until the measurement below, and half of it: an update costs most of the hour, so about twice
    # the env steps for the same updates; does learning follow the data or the updates? (0.125: the preset's since)
    "0.25 updates per step": RATIO_025,
    "half the updates per step": "--updates-per-step 0.125",
    # half again: does learning still follow the env steps?
    "0.0625 updates per step": "--updates-per-step 0.0625",
    # the preset's greedy misses are mostly squares closed at a yaw that does not fit (grasp_failures.py): two levers
    # on them, each against the preset. Pictures of 96x96 (more pixels on a square's edges and in the glimpse), and
    # random actions decayed from 0.3 to 0.05 of collecting steps over the first 150k env steps (more of the data
    # where the greedy policy closes, its near misses included)
    "96-pixel pictures": "--env.image-size 96",
    "less random exploration": "--algo.random-action-prob-end 0.05 --algo.random-action-decay-steps 150000",
    # the Bellman target's maximum over two CEM rounds of 64 candidates refit to 6 elites (QT-Opt's, Kalashnikov et al.
    # 2018) instead of one round of 32: a narrow yaw window is rarely among 32 random candidates, so the value of a
    # state from which a square can be held is underestimated; the candidates pass the MLP only (the pictures are
    # encoded once per state)
    "the paper's bellman maximum": "--algo.target-samples 64 --algo.target-iterations 2 --algo.target-elites 6",
}
SECTIONS = {  # the arms each RESULTS section compares, and its raw data under benchmarks/results/
    "Grasp from pixels: scripted exploration against the preset, equal budgets": (
        ("preset", "scripted exploration"),
        "grasp_learning.json",
    ),
    "Grasp from pixels: a looser hold (tolerance 0.06) as a positive control": (("looser hold",), "grasp_looser_hold.json"),
    "Grasp from pixels: the fair bin's preset for an hour, training and held-out objects": (
        ("fair bin", "independent twins", "adam 1e-3"),
        "grasp_fair_bin.json",
    ),
    "Grasp from pixels: lagged twins and scripted exploration on the fair bin, half an hour": (
        ("independent twins", "lagged twins", "lagged twins + scripted"),
        "grasp_twins.json",
    ),
    "Grasp from pixels: a glimpse in the jaws' frame beside the fair bin's preset": (
        ("fair bin", "glimpse"),
        "grasp_glimpse.json",
    ),
    "Grasp from pixels: the glimpse at Adam 1e-3 against 3e-4": (("glimpse", "glimpse adam 1e-3"), "grasp_glimpse_lr.json"),
    "Grasp from pixels: the preset on both cores (two torch threads) against one": (
        ("glimpse adam 1e-3", "two threads"),
        "grasp_two_threads.json",
    ),
    "Grasp from pixels: half the updates per env step against the preset": (
        ("0.25 updates per step", "half the updates per step"),
        "grasp_update_ratio.json",
    ),
    "Grasp from pixels: 0.0625 updates per env step against the preset's 0.125, one seed": (
        ("half the updates per step", "0.0625 updates per step"),
        "grasp_update_ratio_0625.json",
    ),
    "Grasp from pixels: levers on the squares' yaw against the preset": (
        ("half the updates per step", "96-pixel pictures", "less random exploration", "the paper's bellman maximum"),
        "grasp_squares_levers.json",
    ),
}
#: sections whose runs are also evaluated by `taskrl eval RUN` and `taskrl eval RUN --held-out` (the issue's check)
EVALUATED = (
    "Grasp from pixels: the fair bin's preset for an hour, training and held-out objects",
    "Grasp from pixels: a glimpse in the jaws' frame beside the fair bin's preset",
    "Grasp from pixels: the glimpse at Adam 1e-3 against 3e-4",
    "Grasp from pixels: the preset on both cores (two torch threads) against one",
    "Grasp from pixels: half the updates per env step against the preset",
    "Grasp from pixels: levers on the squares' yaw against the preset",
)
#: half the window of env steps whose evaluations `--at` averages (5 evaluations of 100 attempts at the preset's interval)
WINDOW = 10_000
#: half the window of updates whose evaluations `--at-updates` averages (the same 5 evaluations at 0.25 updates per step)
UPDATE_WINDOW = 2_500


def run(flags: str, seed: int, run_dir: Path, max_hours: float) -> list[dict]:
    if not (run_dir / "learning_curve.png").exists():  # written when a run ends (run.json: when it starts)
        command = [TASKRL, "train", PRESET, "--seed", str(seed), "--threads", "1", "--max-hours", str(max_hours)]
        command += ["--out", str(run_dir), "--no-progress", *shlex.split(flags)]
        subprocess.run(command, check=True, capture_output=True)
    with open(run_dir / "metrics.csv") as f:
        rows = [r for r in csv.DictReader(f) if r.get("success_rate") not in (None, "")]
    keep = ("env_steps", "updates", "wall_seconds", "success_rate", "train_success", "batch_reward")
    curve = [{k: float(r[k]) if r.get(k) not in (None, "") else None for k in keep} for r in rows]
    # a longer run read for a shorter budget: its evaluations up to that budget's wall-clock
    return [row for row in curve if row["wall_seconds"] <= max_hours * 3600]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument(
        "--arms",
        nargs="+",
        type=arm_and_seeds,
        default=[("preset", []), ("scripted exploration", [])],
        help=f"ARM or ARM:S,S (that arm's seeds instead of --seeds); arms: {' | '.join(ARMS)}",
    )
    parser.add_argument("--max-hours", type=float, default=1.3)
    parser.add_argument("--out", default="runs/bench-grasp")
    parser.add_argument("--write", action="store_true", help="replace the RESULTS section of these arms")
    parser.add_argument(
        "--at",
        nargs="*",
        type=int,
        default=[],
        help=f"env steps at which to compare the arms: each run's mean greedy success over its evaluations within "
        f"{WINDOW:,} env steps of each (equal work, whatever the wall-clock)",
    )
    parser.add_argument(
        "--at-updates",
        nargs="*",
        type=int,
        default=[],
        help=f"updates at which to compare the arms: each run's mean greedy success over its evaluations within "
        f"{UPDATE_WINDOW:,} updates of each (for arms that differ in updates per env step)",
    )
    args = parser.parse_args()
    seeds_of = {arm: seeds or args.seeds for arm, seeds in args.arms}
    args.arms = list(seeds_of)
    title, raw_name = section(args.arms)
    results = []
    for arm in args.arms:
        for seed in seeds_of[arm]:
            run_dir = Path(args.out) / f"{re.sub(r'[^a-z0-9]+', '-', arm).strip('-')}-seed{seed}"
            curve = run(ARMS[arm], seed, run_dir, args.max_hours)
            results.append({"arm": arm, "flags": ARMS[arm], "seed": seed, "curve": curve})
            if title in EVALUATED:
                results[-1]["eval"] = evaluate(run_dir)
            print(arm, seed, curve[-1], flush=True)
    raw = Path(__file__).parent / "results" / raw_name
    raw.write_text(json.dumps(results, indent=2) + "\n")
    if args.write:
        report(results, args, title, raw_name)


def arm_and_seeds(text: str) -> tuple[str, list[int]]:
    """``"fair bin:0,1,2"`` -> ("fair bin", [0, 1, 2]); ``"fair bin"`` -> ("fair bin", []): the --seeds."""
    arm, _, seeds = text.partition(":")
    if arm not in ARMS:
        raise argparse.ArgumentTypeError(f"{arm!r}: allowed arms: {' | '.join(ARMS)}")
    try:
        return arm, [int(seed) for seed in seeds.split(",")] if seeds else []
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: seeds after the colon are integers, e.g. 'fair bin:0,1,2'") from None


def evaluate(run_dir: Path) -> dict:
    """``taskrl eval RUN --json`` on the training objects and with ``--held-out`` (100 attempts each): success rates."""
    out = {}
    for name, extra in (("train", []), ("held_out", ["--held-out", "--episodes", "100"])):
        done = subprocess.run([TASKRL, "eval", str(run_dir), "--json", *extra], check=True, capture_output=True, text=True)
        out[name] = json.loads(done.stdout.strip().splitlines()[-1])["success_rate"]
    return out


def at_point(curve: list[dict], point: int, key: str = "env_steps", window: int = WINDOW) -> str:
    """The mean greedy success of ``curve``'s evaluations within ``window`` of ``point`` counted in ``key`` (env steps or
    updates; "-" if the run stopped before ``point``)."""
    if curve[-1][key] < point:
        return "-"
    near = [row["success_rate"] for row in curve if abs(row[key] - point) <= window]
    return f"{sum(near) / len(near):.2f}"


def positives(row: dict) -> str:
    """Rewarded transitions per batch (QT-Opt's ``batch_reward`` x the preset's batch size; runs before it: "-")."""
    return "-" if row["batch_reward"] is None else f"{row['batch_reward'] * BATCH:.1f}"


@functools.cache
def random_floor(objects: str, tolerance: float) -> float:
    """Uniformly random actions' success at this tolerance (10,000 attempts, seed 0): ``grasp_random.py``'s raw data
    where it measured this setting (the same seeded attempts), else measured here."""
    measured = Path(__file__).parent / "results" / "grasp_random.json"
    for row in json.loads(measured.read_text()) if measured.exists() else []:
        if row["objects"] == objects and math.isclose(row["tolerance"], tolerance):
            return row["success"]
    return random_success(objects, tolerance=tolerance)[1]


def tolerance_of(flags: str) -> float:
    words = shlex.split(flags)
    return float(words[words.index("--env.tolerance") + 1]) if "--env.tolerance" in words else GraspSettings.tolerance


def section(arms: list[str]) -> tuple[str, str]:
    """(RESULTS title, raw data file) of the section these arms make."""
    for title, (members, raw) in SECTIONS.items():
        if set(members) == set(arms):
            return title, raw
    raise SystemExit(f"--arms: no section compares {arms}; allowed: {' | '.join(' '.join(m) for m, _ in SECTIONS.values())}")


def report(results: list[dict], args, title: str, raw_name: str) -> None:
    arms_at: dict[float, list[str]] = {}  # tolerance -> the arms run at it
    for arm in args.arms:
        arms_at.setdefault(tolerance_of(ARMS[arm]), []).append(arm)
    lines = [
        f"`taskrl train {PRESET} --seed S --threads 1 --max-hours {args.max_hours}` plus each arm's flags, one process "
        "each, one torch thread unless the arm's flags set `--threads` (what ran beside them: the note); greedy evaluation "
        "on 100 attempts at the training objects every 5,000 env steps; `train success` counts every training attempt, scripted ones included. Uniformly random "
        "actions (`benchmarks/grasp_random.py`, 10,000 attempts): "
        + ", ".join(
            f"{random_floor('train', tolerance):.3f} (tolerance {tolerance}: {', '.join(arms)})"
            for tolerance, arms in arms_at.items()
        )
        + f". Raw curves: `benchmarks/results/{raw_name}`.",
        "",
        "| arm | seed | env steps | updates | wall s | best greedy success (at env steps) | last greedy success | last train success "
        "| positives per batch (last row) |",
        "|---|---|---:|---:|---:|---|---:|---:|---:|",
    ]
    for r in results:
        last = r["curve"][-1]
        best = max(r["curve"], key=lambda row: row["success_rate"])
        flags = f" `{r['flags']}`" if r["flags"] else ""
        lines.append(
            f"| {r['arm']}{flags} | {r['seed']} | {last['env_steps']:,.0f} | {last['updates']:,.0f} | "
            f"{last['wall_seconds']:.0f} | {best['success_rate']:.2f} ({best['env_steps']:,.0f}) | "
            f"{last['success_rate']:.2f} | {last['train_success']:.3f} | {positives(last)} |"
        )
    for points, key, window, unit in (
        (args.at, "env_steps", WINDOW, "env steps"),
        (args.at_updates, "updates", UPDATE_WINDOW, "updates"),
    ):
        if points:
            lines += [
                "",
                f"{' against '.join(args.arms)} at equal {unit} (the mean greedy success of a run's evaluations within "
                f"{window:,} {unit} of each point; -: the run did not reach it):",
                "",
                "| arm | seed | " + " | ".join(f"{n:,}" for n in points) + " |",
                "|---|---|" + "---:|" * len(points),
                *(
                    f"| {r['arm']} | {r['seed']} | " + " | ".join(at_point(r["curve"], n, key, window) for n in points) + " |"
                    for r in results
                ),
            ]
    evaluated = [r for r in results if "eval" in r]
    if evaluated:
        held_out_floor = random_floor("held_out", tolerance_of(ARMS[evaluated[0]["arm"]]))
        lines += [
            "",
            f"After the run ({', '.join(dict.fromkeys(r['arm'] for r in evaluated))}), `taskrl eval RUN --json` (100 "
            "attempts on the training objects) and `taskrl eval RUN --held-out "
            f"--episodes 100 --json` (held-out objects; random actions {held_out_floor:.3f}):",
            "",
            "| arm | seed | training objects | held-out objects |",
            "|---|---|---:|---:|",
            *(f"| {r['arm']} | {r['seed']} | {r['eval']['train']:.2f} | {r['eval']['held_out']:.2f} |" for r in evaluated),
        ]
    lines += ["", "Every evaluation (env steps: greedy success):", ""]
    for r in results:
        points = ", ".join(f"{row['env_steps'] / 1e3:.0f}k: {row['success_rate']:.2f}" for row in r["curve"][1:])
        lines.append(f"- {r['arm']}, seed {r['seed']}: {points}")
    append_results(title, "\n".join(lines))


if __name__ == "__main__":
    main()
