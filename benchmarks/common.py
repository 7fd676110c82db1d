"""Helpers shared by the benchmark scripts: machine description, peak memory, RESULTS.md."""

from __future__ import annotations

import datetime
import os
import platform
import resource
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
    return " ".join([".venv/bin/python", *sys.argv])


def append_results(title: str, body: str) -> None:
    """Append a dated section to benchmarks/RESULTS.md."""
    stamp = datetime.date.today().isoformat()
    text = f"\n## {title}\n\n- date: {stamp}\n- machine: {machine()}\n- command: `{command_line()}`\n\n{body.strip()}\n"
    if not RESULTS.exists():
        RESULTS.write_text("# Benchmark results\n\nEach section was appended by the script named in its command.\n")
    with RESULTS.open("a") as f:
        f.write(text)
