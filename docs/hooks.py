"""mkdocs hooks: the reference pages generated from the code (taskrl.reference), and RESULTS.md as a page."""

from __future__ import annotations

import re
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[1]


def on_files(files, config):
    from taskrl.reference import pages

    for path, text in pages().items():
        files.append(File.generated(config, path, content=text))
    results = (ROOT / "benchmarks" / "RESULTS.md").read_text()
    files.append(File.generated(config, "results.md", content=results))
    return files


def on_page_markdown(markdown, page, config, files):
    # README-style links to the results file point at its page in the site
    depth = page.file.src_uri.count("/")
    return re.sub(r"\]\((?:\.\./)*benchmarks/RESULTS\.md", "](" + "../" * depth + "results.md", markdown)
