"""Seconds a compiled DQN (256, 256) / 256 update spends compiling, with 1 and with 4 updates per call, on a first
run (an empty compile cache) and on a later run of the same shapes (the cache the first run left): taskrl's
``nets.Linear`` (its layouts as plain tensor operations) against the same layouts through an
``autograd.Function`` (``per_call_costs.function_layouts``), which torch's cache of traced graphs refuses
(AOT autograd's "Bypassing autograd cache due to: Unsupported call_function target autograd_function_apply").

Each compile runs in a process of its own, and a first run and its later run share one fresh cache folder; the
seconds are those of both graphs of the target schedule (the update with and without the target refresh).

    cd benchmarks && ../.venv/bin/python compile_cache.py [--repeats 2] [--write]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from common import append_results

PATHS = {"plain": "plain operations (taskrl)", "function": "autograd.Function"}


def child(path: str, per_call: int) -> None:
    """Compile and run one agent's update until both graphs exist; print the compile seconds and cache counters."""
    import torch

    torch.set_num_threads(1)
    from learner_speed import bitflip_agent_and_batch, schedule_period
    from per_call_costs import function_layouts
    from taskrl import nets

    if path == "function":
        nets.Linear.forward = function_layouts
    agent, batch, _ = bitflip_agent_and_batch(256, (256, 256), False)
    agent.compile("default", say=lambda line: None)
    for _ in range(-(-(schedule_period(agent) + 1) // per_call)):
        agent.update_many([batch] * per_call) if per_call > 1 else agent.update(batch)
    step = agent.step_many if per_call > 1 else agent.step
    assert step.active, "the update did not compile"
    counters = dict(torch._dynamo.utils.counters["aot_autograd"])
    print(json.dumps({"seconds": step.compile_seconds, "aot_autograd": counters}))


def measure(path: str, per_call: int, cache: str) -> dict:
    out = subprocess.run(
        [sys.executable, __file__, "--child", path, str(per_call)],
        env={**os.environ, "TORCHINDUCTOR_CACHE_DIR": cache},
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).parent,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--write", action="store_true", help="append the results to benchmarks/RESULTS.md")
    parser.add_argument("--child", nargs=2, metavar=("PATH", "PER_CALL"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        return child(args.child[0], int(args.child[1]))
    runs = {(path, k): {"first": [], "later": [], "counters": []} for path in PATHS for k in (1, 4)}
    for repeat in range(args.repeats):
        order = list(PATHS) if repeat % 2 == 0 else list(PATHS)[::-1]  # the machine's drift on both alike
        for path in order:
            for k in (1, 4):
                cache = tempfile.mkdtemp(prefix="taskrl-inductor-")
                try:
                    first, later = measure(path, k, cache), measure(path, k, cache)
                finally:
                    shutil.rmtree(cache, ignore_errors=True)
                run = runs[path, k]
                run["first"].append(first["seconds"])
                run["later"].append(later["seconds"])
                run["counters"].append(later["aot_autograd"])
                print(path, k, first, later, flush=True)
    rows = [
        f"| {PATHS[path]} | {k} | {statistics.median(r['first']):.1f} ({', '.join(f'{s:.1f}' for s in r['first'])}) | "
        f"{statistics.median(r['later']):.1f} ({', '.join(f'{s:.1f}' for s in r['later'])}) | "
        f"{', '.join(sorted({name for c in r['counters'] for name in c if name.startswith('autograd_cache')}))} |"
        for (path, k), r in runs.items()
    ]
    table = "\n".join(
        [
            f"One torch thread; DQN (256, 256) / 256 on bit flipping n = 15; {args.repeats} repeats, each path's first "
            "and later run in turn; seconds of compiling (both graphs of the target schedule): median (each run).",
            "",
            "| nets.Linear's layouts as | updates per call | first run, s | later run, s | AOT autograd cache, later run |",
            "|---|---|---|---|---|",
            *rows,
        ]
    )
    print(table)
    if args.write:
        append_results("Compile seconds of a first and a later run, side by side", table)
        out = Path(__file__).with_name("results") / "compile_cache.json"
        out.write_text(json.dumps({f"{p}/{k}": r for (p, k), r in runs.items()}, indent=2))


if __name__ == "__main__":
    main()
