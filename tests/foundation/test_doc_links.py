"""Every relative link in README.md and docs/ leads to a file that exists (and, with #anchor, to a heading in it).

Pages move and merge; a reader who follows a link should never land on nothing.
"""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
HEADING = re.compile(r"^#+\s+(.*)$", re.MULTILINE)
HTML_ANCHOR = re.compile(r"<a\s+(?:id|name)=\"([^\"]+)\"")


def _pages() -> list[Path]:
    return sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]


def _anchor(title: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    title = re.sub(r"[`*_]", "", title.strip().lower())
    return re.sub(r"\s", "-", re.sub(r"[^\w\s-]", "", title))


def _anchors(text: str) -> set[str]:
    """The anchors a page offers: its headings' and its explicit <a id="..."> ones."""
    return {_anchor(h) for h in HEADING.findall(text)} | set(HTML_ANCHOR.findall(text))


def broken_links(pages: list[Path]) -> list[str]:
    """'page:line: target (why)' for each relative link that leads nowhere."""
    bad = []
    for page in pages:
        text = page.read_text(encoding="utf-8")
        for match in LINK.finditer(text):
            target = match.group(1)
            if re.match(r"^[a-z]+:", target) or target.startswith("#") and not target[1:]:
                continue  # http(s):, mailto: ...
            path_part, _, anchor = target.partition("#")
            dest = (page.parent / path_part).resolve() if path_part else page
            line = text.count("\n", 0, match.start()) + 1
            where = f"{page.relative_to(ROOT)}:{line}: {target}"
            if not dest.exists():
                bad.append(f"{where} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest.read_text(encoding="utf-8")):
                bad.append(f"{where} (no heading #{anchor})")
    return bad


def test_every_relative_link_in_the_docs_resolves():
    pages = _pages()
    assert len(pages) > 5
    bad = broken_links(pages)
    assert not bad, "links that lead nowhere:\n" + "\n".join(bad)


def test_the_link_check_catches_a_missing_file_and_heading(tmp_path):
    page = tmp_path / "a.md"
    (tmp_path / "b.md").write_text("# Title\n## Two words\n<a id=\"tab\"></a>\n")
    page.write_text("[ok](b.md#two-words) [ok](b.md#tab) [gone](c.md) [bad](b.md#three) [web](https://x.org/y)\n")
    global ROOT
    old, ROOT = ROOT, tmp_path
    try:
        bad = broken_links([page])
    finally:
        ROOT = old
    assert bad == ["a.md:1: c.md (no such file)", "a.md:1: b.md#three (no heading #three)"]
