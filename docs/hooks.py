"""mkdocs hooks: the reference pages generated from the code (taskrl.reference), RESULTS.md as a page with its
figures, and a build that fails on a Sphinx role left raw in a docstring (the renderer does not read them)."""

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
    for figure in sorted((ROOT / "benchmarks" / "figures").glob("*.png")):  # what the results page embeds
        files.append(File.generated(config, f"figures/{figure.name}", content=figure.read_bytes()))
    return files


#: a Sphinx cross-reference role as it comes out of the markdown renderer (``:func:`x``` -> ``:func:<code>x</code>``)
RAW_ROLE = re.compile(r":(?:func|class|meth|mod|attr|data|exc|obj|ref):<code>")


def on_page_content(html, page, config, files):
    found = RAW_ROLE.search(html)
    if found:
        from mkdocs.exceptions import PluginError

        context = re.sub(r"<[^>]+>", "", html[found.start() : found.start() + 400])[:60]
        raise PluginError(
            f"{page.file.src_uri}: a raw Sphinx role ({context.strip()}...): write [`name`][taskrl.module.name] or `name`"
        )
    return html


def on_page_markdown(markdown, page, config, files):
    # README-style links to the results file point at its page in the site
    depth = page.file.src_uri.count("/")
    return re.sub(r"\]\((?:\.\./)*benchmarks/RESULTS\.md", "](" + "../" * depth + "results.md", markdown)
