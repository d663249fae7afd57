"""The documentation cannot drift: docs/metrics.md is what its generator gives from `METRICS` now, the
README stays a front door (at most 200 lines), and every relative link points to a file (and a section)
that exists."""

import glob
import os
import re

from tests.conftest import ROOT
from vrsim.services.outputs import metrics_doc

README = os.path.join(ROOT, "README.md")
PAGES = [README, os.path.join(ROOT, "bench", "README.md"),
         *sorted(glob.glob(os.path.join(ROOT, "docs", "*.md")))]
FENCE = re.compile(r"^```.*?^```", re.M | re.S)  # code blocks: their brackets are code, not links
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def slug(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(path: str) -> set[str]:
    """The anchors of the headings of the Markdown file at `path` (none for another kind of file)."""
    if not path.endswith(".md"):
        return set()
    with open(path, encoding="utf-8") as f:
        text = FENCE.sub("", f.read())
    return {slug(h) for h in re.findall(r"^#+ (.+)$", text, re.M)}


def broken_links(text: str, path: str) -> list[str]:
    """The relative link targets in Markdown `text` (the file at `path`) that name no file or folder,
    or a section that the named Markdown file (or this one, for ``#section``) does not have."""
    folder = os.path.dirname(path)
    bad = []
    for target in LINK.findall(FENCE.sub("", text)):
        if re.match(r"[a-z]+:", target):
            continue
        name, _, section = target.partition("#")
        linked = os.path.join(folder, name) if name else path
        if not os.path.exists(linked) or (section and section not in anchors(linked)):
            bad.append(target)
    return bad


def test_metrics_page_is_what_the_generator_gives_from_metrics_now():
    with open(os.path.join(ROOT, "docs", "metrics.md"), encoding="utf-8") as f:
        committed = f.read()
    assert committed == metrics_doc.page(), \
        "docs/metrics.md is stale: python -m vrsim.services.outputs.metrics_doc > docs/metrics.md"


def test_metrics_page_lists_every_figure_with_its_unit():
    page = metrics_doc.page()
    for m in metrics_doc.metrics.METRICS:
        assert f"| `{m.key}` | {m.unit} |" in page


def test_readme_is_at_most_200_lines():
    with open(README, encoding="utf-8") as f:
        assert len(f.read().splitlines()) <= 200


def test_every_relative_link_of_the_readme_and_docs_names_a_file_that_exists():
    broken = {}
    for path in PAGES:
        with open(path, encoding="utf-8") as f:
            bad = broken_links(f.read(), path)
        if bad:
            broken[os.path.relpath(path, ROOT)] = bad
    assert broken == {}


def test_the_link_check_finds_missing_files_and_sections_and_skips_urls_and_code(tmp_path):
    (tmp_path / "there.md").write_text("# There\n## The web page: `vrsim serve web`\n")
    page = tmp_path / "page.md"
    text = ("# Page\n[a](there.md) [b](there.md#the-web-page-vrsim-serve-web) [c](missing.md) "
            "![d](img/gone.png) [e](https://x.org/y) [f](#page) [g](#nowhere) [h](there.md#gone)\n"
            "```\n[i](in_code.md)\n# not a heading\n```\n")
    page.write_text(text)
    assert broken_links(text, str(page)) == ["missing.md", "img/gone.png", "#nowhere", "there.md#gone"]
