"""The documentation cannot drift: docs/metrics.md is what its generator gives from `METRICS` now, the
README stays a front door (at most 200 lines), and every relative link points to a file that exists."""

import glob
import os
import re

from services.outputs import metrics_doc
from tests.conftest import ROOT

README = os.path.join(ROOT, "README.md")
PAGES = [README, os.path.join(ROOT, "bench", "README.md"),
         *sorted(glob.glob(os.path.join(ROOT, "docs", "*.md")))]
FENCE = re.compile(r"^```.*?^```", re.M | re.S)  # code blocks: their brackets are code, not links
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def broken_links(text: str, folder: str) -> list[str]:
    """The relative link targets in Markdown `text` that name no file or folder under `folder`."""
    targets = LINK.findall(FENCE.sub("", text))
    local = [t.split("#")[0] for t in targets if not re.match(r"[a-z]+:|#", t)]
    return [t for t in local if t and not os.path.exists(os.path.join(folder, t))]


def test_metrics_page_is_what_the_generator_gives_from_metrics_now():
    with open(os.path.join(ROOT, "docs", "metrics.md"), encoding="utf-8") as f:
        committed = f.read()
    assert committed == metrics_doc.page(), \
        "docs/metrics.md is stale: python -m services.outputs.metrics_doc > docs/metrics.md"


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
            bad = broken_links(f.read(), os.path.dirname(path))
        if bad:
            broken[os.path.relpath(path, ROOT)] = bad
    assert broken == {}


def test_the_link_check_finds_a_missing_file_and_skips_urls_anchors_and_code(tmp_path):
    (tmp_path / "there.md").write_text("")
    text = ("[a](there.md) [b](there.md#part) [c](missing.md) ![d](img/gone.png) [e](https://x.org/y) "
            "[f](#anchor)\n```\n[g](in_code.md)\n```\n")
    assert broken_links(text, str(tmp_path)) == ["missing.md", "img/gone.png"]
