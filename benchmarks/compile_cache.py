"""Seconds a compiled DQN (256, 256) / 256 update spends compiling, with 1 and with 4 updates per call, on a first
run (an empty compile cache) and on a later run of the same shapes (the cache the first run left).

taskrl's ``nets.Linear`` takes its training layouts through an ``autograd.Function``, which torch's cache of
traced graphs refuses (AOT autograd: "Bypassing autograd cache due to: Unsupported call_function target
autograd_function_apply"), so a later run traces the update again. It runs side by side with the same layouts
as plain tensor operations (:func:`plain_operation_layouts`, tried and not kept), which that cache takes.

Each compile runs in a process of its own, and a first run and its later run share one fresh cache folder; the
seconds are those of both graphs of the target schedule (the update with and without the target refresh).

    cd benchmarks && ../.venv/bin/python compile_cache.py [--repeats 2] [--write]
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from common import append_results

PATHS = {"function": "an autograd.Function (taskrl)", "plain": "plain operations (tried)"}


def plain_operation_layouts(self, x):
    """``nets.Linear``'s compiled layouts with torch's own derivatives: the padded head as ``F.pad`` and a slice,
    the wide weight gradient through a transposed copy of ``W`` (autograd lays ``dW`` out as the product's
    weight operand is laid out). The same bits as taskrl's ``autograd.Function`` after 1 and 250 compiled updates
    of this benchmark's agent, and the same time per update (per_call_costs.py's pair 'layouts' at commit c8adb49:
    1.004x)."""
    import torch
    import torch.nn.functional as F

    from taskrl import nets

    pad = -self.out_features % 16 if self.out_features % 16 >= 13 else 0
    needs_grad = torch.is_grad_enabled() and (x.requires_grad or self.weight.requires_grad or self.bias.requires_grad)
    wide_grad = self.in_features < self.out_features and needs_grad
    if (
        not (pad or wide_grad)
        or (needs_grad and not torch.compiler.is_compiling())
        or x.numel() // self.in_features * self.in_features * self.out_features < nets._LAYOUT_MIN_MACS
    ):
        return F.linear(x, self.weight, self.bias)
    weight, bias = self.weight, self.bias
    if pad:
        weight, bias = F.pad(weight, (0, 0, 0, pad)), F.pad(bias, (0, pad))
    if wide_grad:
        weight = weight.t().contiguous().t()
    y = F.linear(x, weight, bias)
    return y[..., : self.out_features] if pad else y


def child(path: str, per_call: int) -> None:
    """Compile and run one agent's update until both graphs exist; print the compile seconds and cache counters."""
    import torch

    torch.set_num_threads(1)
    from learner_speed import bitflip_agent_and_batch, schedule_period
    from taskrl import nets
    from taskrl.replay.batch import Batch

    if path == "plain":
        nets.Linear.forward = plain_operation_layouts
    agent, batch, _ = bitflip_agent_and_batch(256, (256, 256), False)
    if per_call > 1:
        together = Batch.interleave([batch] * per_call)
        update = functools.partial(agent.update_many, together, per_call)
    else:
        update = functools.partial(agent.update, batch)
    agent.compile("default", say=lambda line: None)
    for _ in range(-(-(schedule_period(agent) + 1) // per_call)):
        update()
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
