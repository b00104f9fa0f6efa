"""The results page: short, every raw row it keeps cited, one naming rule, and links that resolve."""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "benchmarks" / "RESULTS.md"
RESULTS = ROOT / "benchmarks" / "results"
MAX_CHARS = 40_000
APPENDED = "all-views"
"""A running benchmark appends to this folder's files under the names it was started with."""
WORDS = re.compile(r"[a-z0-9]+(-[a-z0-9]+)*")
NAME = re.compile(WORDS.pattern + r"(\.[a-z0-9]+)+")
LINK = re.compile(r"\]\(([^)\s]+)\)|^\[[^\]]+\]:\s*(\S+)", re.MULTILINE)


def slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces as hyphens."""
    kept = (c for c in heading.strip().lower()
            if c in " -" or unicodedata.category(c)[0] in "LMN" or unicodedata.category(c) == "Pc")
    return "".join(kept).replace(" ", "-")


def anchors(text: str) -> set[str]:
    """Every heading anchor of a markdown text (a repeated heading gets -1, -2, ...)."""
    seen: dict[str, int] = {}
    fenced = False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        match = None if fenced else re.match(r"#{1,6} (.*)", line)
        if match:
            name = slug(match.group(1))
            seen[name] = seen.get(name, -1) + 1
            if seen[name]:
                seen[f"{name}-{seen[name]}"] = 0
    return set(seen)


def kept_rows() -> list[Path]:
    return sorted(p for p in RESULTS.rglob("*") if p.is_file())


def test_the_page_stays_short():
    assert len(PAGE.read_text()) <= MAX_CHARS


def test_every_kept_raw_row_is_cited_by_the_page():
    text = PAGE.read_text()
    uncited = [str(p.relative_to(RESULTS)) for p in kept_rows()
               if f"results/{p.relative_to(RESULTS).as_posix()}" not in text]
    assert not uncited, f"cite these on RESULTS.md or move them to benchmarks/archive/results/: {uncited}"


def test_kept_raw_rows_follow_one_naming_rule():
    """Lowercase words and digits joined by hyphens, for folders and files alike."""
    bad = []
    for path in kept_rows():
        *folders, name = path.relative_to(RESULTS).parts
        if folders[:1] != [APPENDED] and not (NAME.fullmatch(name)
                                               and all(WORDS.fullmatch(f) for f in folders)):
            bad.append(path.relative_to(RESULTS).as_posix())
    assert not bad


def test_links_of_the_results_page_readme_and_docs_resolve():
    broken = []
    for page in (PAGE, ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))):
        for match in LINK.finditer(page.read_text()):
            target = match.group(1) or match.group(2)
            if target.startswith(("http://", "https://")):
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if not file.exists():
                broken.append(f"{page.name}: {target}")
            elif anchor and file.suffix == ".md" and anchor not in anchors(file.read_text()):
                broken.append(f"{page.name}: {target} (no such heading)")
    assert not broken, broken


def test_slug_matches_github_on_a_heading_with_code_and_punctuation():
    assert slug("The inv_s floor, rerun: `neus` at 2x (issue 19, 2026-11-27 18:10)") == (
        "the-inv_s-floor-rerun-neus-at-2x-issue-19-2026-11-27-1810")
