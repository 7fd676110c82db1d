"""benchmarks/RESULTS.md as a report: one chapter per question, one current section per measurement.

Every benchmark script writes its section through ``common.append_results``, which calls
:func:`organise`: the section replaces the one with the same title (or the same question where
titles carry a commit, as in ``Same learning as commit ...``), and the file is laid out again
chapter by chapter in the order of :data:`QUESTIONS`, with a table of contents. Older figures live in
git history and in ``benchmarks/results/``.

    .venv/bin/python benchmarks/report.py          # lay out RESULTS.md again (idempotent)
    .venv/bin/python benchmarks/report.py --check  # exit 1 if it is not laid out (a test runs this)
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

RESULTS = Path(__file__).with_name("RESULTS.md")

#: (anchor, chapter title, section titles that belong to it by prefix), in the report's order.
QUESTIONS: list[tuple[str, str, tuple[str, ...]]] = [
    ("tabular", "Exact dynamic programming", ("Tabular dynamic programming",)),
    (
        "bit-flipping",
        "Hindsight relabelling on bit flipping, and against Stable-Baselines3",
        ("Bit flipping", "Plain DQN", "DQN + hindsight relabelling vs Stable-Baselines3"),
    ),
    ("replay", "Replay and checkpoint memory", ("Replay memory", "Checkpoint memory")),
    (
        "continuous",
        "Continuous control: PointReach and Fetch (SAC, QT-Opt)",
        ("Presets: pointreach", "SAC + hindsight relabelling", "QT-Opt", "FetchPush"),
    ),
    ("meta-world", "Meta-World (MT1, MT10)", ("SAC throughput on Meta-World", "Meta-World")),
    ("sharing", "Data sharing between tasks", ("Data sharing",)),
    ("imitation", "Multi-task imitation (BC-Z)", ("Multi-task behaviour cloning", "Demonstration collection")),
    ("distributed", "Distributed training", ("Distributed",)),
    ("camera", "Learning from the camera", ("Grasp", "Goal pictures")),
    (
        "learner-speed",
        "Learner speed: compiled updates, the FLOP bound, equal work against Stable-Baselines3",
        (
            "Learner speed",
            "Learning with compiled updates",
            "Same learning as commit",
            "Per-call costs",
            "Where the time",
            "Compile seconds",
            "CPU product layouts",
        ),
    ),
]
OTHER = ("other", "Other measurements", ())

HEAD = """# Benchmark results

What taskrl measured, one chapter per question. Each section names the commit it was measured at,
the date, the machine and the command that wrote it (`benchmarks/*.py --write`); the per-seed data of
runs from 2026-12-01 on are under `benchmarks/results/`, the figures under `benchmarks/figures/`.
A ratio against another library says what it compares: **each library with its own (recommended)
settings** (the differences are listed next to it), or **equal work** (same network, batch, number of
envs, updates per env step). A new measurement of the same question replaces the old section (git
keeps the history); AMD EPYC and Intel Xeon machines do not compare figure for figure.
"""

#: titles that name the commit they compare with: one current section for all of them
_SAME_QUESTION = [re.compile(r"^Same learning as commit \w+")]


def question_key(title: str) -> str:
    for pattern in _SAME_QUESTION:
        match = pattern.match(title)
        if match:
            return pattern.pattern
    return title


def chapter_of(title: str) -> tuple[str, str, tuple[str, ...]]:
    for chapter in QUESTIONS:
        if any(title.startswith(prefix) for prefix in chapter[2]):
            return chapter
    return OTHER


def sections(text: str) -> list[tuple[str, str]]:
    """``(title, body)`` of every ``### title`` section (``## `` sections of the older flat layout too)."""
    found: list[tuple[str, str]] = []
    level = "### " if "\n### " in text else "## "
    parts = re.split(rf"\n{re.escape(level)}", "\n" + text)
    for part in parts[1:]:
        title, _, body = part.partition("\n")
        # a chapter heading or anchor left at the end of the previous section is not part of it
        body = re.sub(r"\n(## [^\n]*|<a id=[^\n]*>\s*</a>|- \[[^\n]*\]\(#[^\n]*\))\s*(?=\n|$)", "\n", body)
        found.append((title.strip(), body.strip("\n")))
    return found


def organise(text: str) -> str:
    """The report: the newest section per title (per question for titles carrying a commit), grouped by chapter."""
    latest: dict[str, tuple[str, str]] = {}
    for title, body in sections(text):
        latest.pop(question_key(title), None)  # the newer one takes the place of the older
        latest[question_key(title)] = (title, body)
    chapters = [*QUESTIONS, OTHER]
    grouped: dict[str, list[tuple[str, str]]] = {anchor: [] for anchor, _, _ in chapters}
    for title, body in latest.values():
        grouped[chapter_of(title)[0]].append((title, body))
    contents = ["## Contents", ""]
    out: list[str] = []
    for anchor, name, _ in chapters:
        if not grouped[anchor]:
            continue
        contents.append(f"- [{name}](#{anchor}): " + "; ".join(_short(t) for t, _ in grouped[anchor]))
        out += ["", f'<a id="{anchor}"></a>', "", f"## {name}", ""]
        for title, body in grouped[anchor]:
            out += [f"### {title}", "", body.strip("\n"), ""]
    return HEAD + "\n" + "\n".join(contents) + "\n" + "\n".join(out).rstrip("\n") + "\n"


def _short(title: str) -> str:
    return title if len(title) <= 70 else title[:67].rstrip() + "..."


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true", help="exit 1 if RESULTS.md is not laid out")
    args = parser.parse_args()
    text = RESULTS.read_text()
    laid_out = organise(text)
    if args.check:
        if laid_out != text:
            print("benchmarks/RESULTS.md is not laid out: run .venv/bin/python benchmarks/report.py", file=sys.stderr)
            return 1
        return 0
    RESULTS.write_text(laid_out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
