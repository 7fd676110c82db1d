"""Wall time and peak memory of ``taskrl demos collect`` (one process, as a user runs it), and its dataset's size.

.venv/bin/python benchmarks/demos_collect.py --source mt10 --episodes 50 --noise 0.1
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import append_results  # noqa: E402

TASKRL = str(Path(sys.executable).with_name("taskrl"))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--source", default="mt10")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--noise", type=float, default=0.1)
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp())
    out = folder / "demos"
    try:
        command = [TASKRL, "demos", "collect", args.source, "--episodes", str(args.episodes), "--noise", str(args.noise)]
        command += ["--out", str(out), "--no-progress"]
        start = time.perf_counter()
        subprocess.run(["/usr/bin/time", "-f", "%M", "-o", str(folder / "rss"), *command], check=True, capture_output=True)
        seconds = time.perf_counter() - start
        peak = int((folder / "rss").read_text().strip().splitlines()[-1]) / 1024
        card = json.loads(subprocess.run([TASKRL, "demos", "info", str(out), "--json"], capture_output=True, check=True).stdout)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    success = card["card"]["expert_success_rate"]
    body = (
        f"`taskrl demos collect {args.source} --episodes {args.episodes} --noise {args.noise}`, one process, nothing else running: "
        f"{seconds:.0f} s wall, peak {peak:.0f} MiB; {card['total_episodes']:,} episodes, {card['total_steps']:,} steps, "
        f"{card['dataset_size']} MB on disk. Expert success per task (kept / attempted): lowest "
        f"{min(success.values()):.2f} ({min(success, key=success.get)}), mean {sum(success.values()) / len(success):.3f}."
    )
    print(body)
    append_results(f"Demonstration collection: {args.source}", body)


if __name__ == "__main__":
    main()
