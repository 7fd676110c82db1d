"""Helpers shared by the benchmark scripts: machine description, peak memory, RESULTS.md."""

from __future__ import annotations

import datetime
import os
import platform
import resource
import shlex
import sys
from pathlib import Path

RESULTS = Path(__file__).with_name("RESULTS.md")


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import torch

    return f"{os.cpu_count()} cores ({cpu}), {platform.system()}, Python {platform.python_version()}, torch {torch.__version__}"


def peak_rss_mib() -> float:
    """Peak resident memory of this process (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def command_line() -> str:
    return shlex.join([".venv/bin/python", *sys.argv])


def commit() -> str:
    """The checked-out commit the figures are measured with (``+changes`` if the tree differs from it)."""
    import subprocess

    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + (" +changes" if dirty.strip() else "")


def fresh_compile_cache() -> str:
    """Point torch's compile cache at a new empty folder, removed when the process ends (unless
    ``TORCHINDUCTOR_CACHE_DIR`` is already set): compile times measured are those of a first run, since a
    later run of the same shapes reuses the on-disk cache and starts faster. Call before the first compile."""
    import atexit
    import shutil
    import tempfile

    if "TORCHINDUCTOR_CACHE_DIR" not in os.environ:
        folder = tempfile.mkdtemp(prefix="taskrl-inductor-")
        atexit.register(shutil.rmtree, folder, ignore_errors=True)
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = folder
    return os.environ["TORCHINDUCTOR_CACHE_DIR"]


def micro_benchmark_args(doc: str | None, choices: tuple[str, ...] = ()):
    """The command line of a micro-benchmark (``--write``; ``--only`` some of ``choices``), with one torch thread
    and a fresh compile cache (:func:`fresh_compile_cache`)."""
    import argparse

    import torch

    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--write", action="store_true", help="append the results to benchmarks/RESULTS.md")
    if choices:
        parser.add_argument("--only", nargs="+", choices=choices, default=list(choices), help="what to measure (default: all)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    fresh_compile_cache()
    return args


def alternating_blocks(blocks: dict, rounds: int, before_round=None) -> dict[str, list[float]]:
    """Milliseconds per unit of each of ``blocks`` (name -> a call that runs one block and returns how many
    units it did), round by round, the first of each round rotating, so the machine's drift falls on all alike;
    ``before_round()`` runs at the start of each round."""
    import time

    names, ms = list(blocks), {name: [] for name in blocks}
    for r in range(rounds):
        if before_round is not None:
            before_round()
        for name in names[r % len(names) :] + names[: r % len(names)]:
            start = time.perf_counter()
            units = blocks[name]()
            ms[name].append((time.perf_counter() - start) / units * 1e3)
    return ms


def append_results(title: str, body: str) -> None:
    """Write a dated section to benchmarks/RESULTS.md, naming the commit it was measured at. It replaces the
    section with the same title (a new measurement of the same question replaces the old; git keeps history),
    and the report is laid out again chapter by chapter (``report.py``)."""
    from report import organise

    stamp = datetime.date.today().isoformat()
    text = (
        f"\n### {title}\n\n- measured at commit: {commit()}\n- date: {stamp}\n- machine: {machine()}\n"
        f"- command: `{command_line()}`\n\n{body.strip()}\n"
    )
    current = RESULTS.read_text() if RESULTS.exists() else ""
    RESULTS.write_text(organise(current.rstrip("\n") + "\n" + text))


def taskrl_learn_until(preset: str, seed: int, budget: int, eval_interval: int, target: float, **settings) -> dict:
    """Train a taskrl preset (with ``settings``) until evaluation success reaches ``target`` (0: the whole
    ``budget``), in a temporary run directory; evaluation excluded from its clock (``wall_seconds``)."""
    import tempfile

    import taskrl

    with tempfile.TemporaryDirectory() as tmp:
        run = taskrl.train(
            preset,
            out=Path(tmp) / "run",
            seed=seed,
            total_steps=budget,
            eval_interval=eval_interval,
            stop_at_success=target,
            tensorboard=False,
            checkpoint_interval=10**12,
            save_replay=False,
            **settings,
        )
    m = run.metrics
    return {
        "solved": target > 0 and m["success_rate"] >= target,
        "env_steps": m["env_steps"],
        "updates": m["updates"],
        "seconds": m["wall_seconds"],
        "env_steps_per_s": m["env_steps"] / max(m["wall_seconds"], 1e-9),
        "updates_per_s": m["updates"] / max(m["wall_seconds"], 1e-9),
        "final_success": m["success_rate"],
        "path": f"compile {run.config.compile}, {run.config.updates_per_call} per call",  # as settled (auto included)
        # every compiled step's (one update, and K per call)
        "compile_seconds": sum(getattr(getattr(run.agent, name, None), "compile_seconds", 0.0) for name in ("step", "step_many")),
    }


def sb3_learn_until(model, evaluate_fn, eval_interval: int, target: float, budget: int) -> dict:
    """Train a Stable-Baselines3 model, evaluating every ``eval_interval`` env steps with
    ``evaluate_fn(model) -> success rate``; stop at ``target``. The clock excludes evaluation,
    as taskrl's ``wall_seconds`` does."""
    import time

    from stable_baselines3.common.callbacks import BaseCallback

    result = {"solved": False, "final_success": 0.0, "env_steps": 0, "seconds": 0.0}

    class EvalAndClock(BaseCallback):
        def _on_training_start(self) -> None:
            self.train_seconds, self.started, self.next_eval = 0.0, time.perf_counter(), eval_interval

        def _on_step(self) -> bool:
            if self.num_timesteps < self.next_eval:
                return True
            self.train_seconds += time.perf_counter() - self.started
            self.next_eval += eval_interval
            success = evaluate_fn(self.model)
            result.update(env_steps=self.num_timesteps, seconds=self.train_seconds, final_success=success)
            self.started = time.perf_counter()
            if success >= target:
                result["solved"] = True
                return False
            return True

    model.learn(total_timesteps=budget, callback=EvalAndClock())
    result["env_steps_per_s"] = result["env_steps"] / max(result["seconds"], 1e-9)
    return result


def median_table(runs: list[dict], keys: list, libs: list[str], key_name: str) -> tuple[str, dict]:
    """Markdown table of medians per (key, library); unsolved runs count at their budget."""
    import statistics

    lines = [
        f"| {key_name} | library | solved (seeds) | median env steps to 90% | median seconds to 90% | median env steps/s |",
        "|---|---|---|---|---|---|",
    ]
    medians = {}
    for key in keys:
        for lib in libs:
            rs = [r for r in runs if r["key"] == key and r["lib"] == lib]
            solved = sum(r["solved"] for r in rs)
            steps = statistics.median(r["env_steps"] for r in rs)
            secs = statistics.median(r["seconds"] for r in rs)
            sps = statistics.median(r["env_steps_per_s"] for r in rs)
            medians[(key, lib)] = (steps, secs, sps, solved == len(rs))
            lines.append(f"| {key} | {lib} | {solved}/{len(rs)} | {steps:,.0f} | {secs:.1f} | {sps:,.0f} |")
    if set(libs) == {"taskrl", "sb3"}:
        lines += [
            "",
            "Ratios of medians (training env steps/s: each library with its own settings, learning included):",
            "",
            f"| {key_name} | wall-clock ratio (SB3 / taskrl) | env-step ratio (SB3 / taskrl) | env steps/s ratio (taskrl / SB3) |",
            "|---|---|---|---|",
        ]
        for key in keys:
            t, s = medians[(key, "taskrl")], medians[(key, "sb3")]
            note = "" if s[3] else " (SB3 did not solve every seed: its time is the budget, so the ratio is a lower bound)"
            lines.append(f"| {key} | {s[1] / t[1]:.1f}x{note} | {s[0] / t[0]:.1f}x | {t[2] / s[2]:.1f}x |")
    return "\n".join(lines), medians
