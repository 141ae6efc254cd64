"""Every link in the repository's Markdown resolves inside the repository: relative paths that exist (and
headings that exist, for #anchors); README.md and docs/ link to nothing outside it (a fresh clone offline
has every page they point to). The CTU data set's own README, a copy as published, may cite its sources."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)
OURS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def markdown_files() -> list[Path]:
    skip = {".git", ".venv", "node_modules", "build"}
    return [p for p in sorted(ROOT.rglob("*.md")) if not skip & set(p.relative_to(ROOT).parts)]


def links(path: Path) -> list[str]:
    return LINK.findall(FENCE.sub("", path.read_text(encoding="utf-8")))


def anchors(path: Path) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to hyphens."""
    text = FENCE.sub("", path.read_text(encoding="utf-8"))
    headings = re.findall(r"^#+\s+(.+?)\s*$", text, re.M)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in headings}


def test_relative_links_resolve_inside_the_repository():
    broken = []
    for md in markdown_files():
        for target in links(md):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):  # a URL: checked for our pages below
                continue
            file_part, _, anchor = target.partition("#")
            resolved = (md.parent / file_part).resolve() if file_part else md
            where = f"{md.relative_to(ROOT)}: {target}"
            if not resolved.is_relative_to(ROOT):
                broken.append(f"{where} leaves the repository")
            elif not resolved.exists():
                broken.append(f"{where} does not exist")
            elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
                broken.append(f"{where}: no heading #{anchor}")
    assert broken == []


def test_the_readme_and_docs_link_only_inside_the_repository():
    outside = [
        f"{md.relative_to(ROOT)}: {t}" for md in OURS for t in links(md) if re.match(r"^[a-z][a-z0-9+.-]*:", t, re.I)
    ]
    assert outside == []
    assert len(links(ROOT / "README.md")) > 10  # the check sees the links
