"""benchmarks/RESULTS.md as a report: one chapter per question, one current section per measurement.

Every benchmark script writes its section through ``common.append_results``, which calls
:func:`organise`: the section replaces the one with the same title (or the same question where
titles carry a commit, as in ``Same learning as commit ...``), and the file is laid out again
chapter by chapter in the order of :data:`QUESTIONS`, with a table of contents. Older figures live in
git history and in ``benchmarks/results/``.

The report opens with a summary (``benchmarks/summary.md``, kept by hand: one line per question, our figure
beside the published or peer figure, linked to its chapter). Figures are shown, not named: a figure's path in a
section becomes a link and the picture is embedded in the section. ``--check`` also enforces the shape: the
summary links only to chapters that exist, every figure under ``benchmarks/figures/`` is embedded and every
embedded one exists, no chapter repeats a paragraph, no raw data is pasted (a line over 1,000 characters).

    .venv/bin/python benchmarks/report.py          # lay out RESULTS.md again (idempotent)
    .venv/bin/python benchmarks/report.py --check  # exit 1 if it is not laid out (a test runs this)
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

RESULTS = Path(__file__).with_name("RESULTS.md")
SUMMARY = Path(__file__).with_name("summary.md")
FIGURES = Path(__file__).with_name("figures")
#: a figure named by its path in a section: `benchmarks/figures/NAME.png` (or `figures/NAME.png`)
_FIGURE_PATH = re.compile(r"`(?:benchmarks/)?figures/([\w.-]+\.png)`")
_EMBEDDED = re.compile(r"!\[[^\]]*\]\(figures/([\w.-]+\.png)\)")
LONGEST_LINE = 1_000

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
    ("camera", "Learning from the camera", ("Grasp", "KukaGrasp", "Goal pictures")),
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


def show_figures(body: str) -> str:
    """A section's figure paths as links, and each of its figures embedded (at the section's end if not yet)."""
    named = _FIGURE_PATH.findall(body)
    body = _FIGURE_PATH.sub(lambda m: f"[{m.group(1)}](figures/{m.group(1)})", body)
    shown = set(_EMBEDDED.findall(body))
    missing = [name for name in dict.fromkeys(named) if name not in shown]
    return body + "".join(f"\n\n![{name[:-4]}](figures/{name})" for name in missing)


def organise(text: str) -> str:
    """The report: the summary, then the newest section per title (per question for titles carrying a commit),
    grouped by chapter, figures shown."""
    latest: dict[str, tuple[str, str]] = {}
    for title, body in sections(text):
        if title == "Summary":
            continue
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
        contents.append(_contents_line(name, anchor, [t for t, _ in grouped[anchor]]))
        out += ["", f'<a id="{anchor}"></a>', "", f"## {name}", ""]
        for title, body in grouped[anchor]:
            out += [f"### {title}", "", show_figures(body.strip("\n")), ""]
    summary = ["## Summary", "", SUMMARY.read_text().strip("\n"), ""] if SUMMARY.exists() else []
    return HEAD + "\n" + "\n".join([*summary, *contents]) + "\n" + "\n".join(out).rstrip("\n") + "\n"


def _contents_line(name: str, anchor: str, titles: list[str]) -> str:
    """A chapter's line of the contents: its section titles, as many as fit the longest line, then how many more."""
    head, shown = f"- [{name}](#{anchor}): ", []
    for k, title in enumerate(titles):
        rest = len(titles) - k - 1
        tail = f"; and {rest} more" if rest else ""
        if len(head + "; ".join([*shown, title]) + tail) > LONGEST_LINE - 20:
            return head + "; ".join(shown) + f"; and {len(titles) - k} more"
        shown.append(title)
    return head + "; ".join(shown)


def problems(text: str) -> list[str]:
    """What keeps ``text`` from being the report's shape (module docstring), one line each."""
    found = []
    if organise(text) != text:
        found.append("it is not laid out: run .venv/bin/python benchmarks/report.py")
    if not SUMMARY.exists():
        found.append(f"{SUMMARY.name} is missing: the report opens with a summary")
    else:
        anchors = {anchor for anchor, _, _ in [*QUESTIONS, OTHER]}
        for link in re.findall(r"\]\(#([\w-]+)\)", SUMMARY.read_text()):
            if link not in anchors:
                found.append(f"the summary links to #{link}, which is no chapter")
    embedded = _EMBEDDED.findall(text)
    for name in sorted({p.name for p in FIGURES.glob("*.png")} - set(embedded)):
        found.append(f"figures/{name} is shown nowhere: embed it in its section or delete it")
    for name in sorted(set(embedded)):
        if not (FIGURES / name).exists():
            found.append(f"figures/{name} is embedded but does not exist")
    for number, line in enumerate(text.splitlines(), 1):
        if len(line) > LONGEST_LINE:
            found.append(f"line {number} has {len(line):,} characters: raw data goes to benchmarks/results/*.json")
    for chapter in re.split(r"\n## ", text):
        seen: dict[str, int] = {}
        for paragraph in re.split(r"\n\s*\n", chapter):
            paragraph = paragraph.strip()
            if len(paragraph) >= 100 and not paragraph.startswith(("|", "- [", "![")):
                seen[paragraph] = seen.get(paragraph, 0) + 1
        for paragraph, count in seen.items():
            if count > 1:
                name = chapter.partition("\n")[0]
                found.append(f"chapter {name!r} repeats a paragraph {count} times (say it once): {paragraph[:70]}...")
    return found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--check", action="store_true", help="exit 1 if RESULTS.md is not laid out")
    args = parser.parse_args()
    text = RESULTS.read_text()
    laid_out = organise(text)
    if args.check:
        found = problems(text)
        for problem in found:
            print(f"benchmarks/RESULTS.md: {problem}", file=sys.stderr)
        return 1 if found else 0
    RESULTS.write_text(laid_out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
