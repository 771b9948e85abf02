"""The README and the documents point only at files and headings that exist: every relative
Markdown link resolves (its ``#anchor`` to a heading of the target, as GitHub names it), and
every ``docs/NAME.md`` named in their prose is a document of ``docs/``."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: A Markdown link's target: ``[text](target)``, target without spaces.
LINK = re.compile(r"\]\(([^)\s]+)\)")


def github_anchor(heading: str) -> str:
    """A heading's anchor as GitHub makes it: lower case, punctuation dropped (word characters,
    hyphens and spaces kept), each space a hyphen."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """The anchors of a Markdown page's headings (lines in code fences are not headings)."""
    found: set[str] = set()
    in_fence = False
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.startswith("```"):
            in_fence = not in_fence
        elif not in_fence and re.match(r"#{1,6} ", line):
            found.add(github_anchor(line.lstrip("#")))
    return found


def test_github_anchor_drops_punctuation_and_joins_words_with_hyphens() -> None:
    assert github_anchor("The test suite's run times (`pytest --all`, `pytest`)") == (
        "the-test-suites-run-times-pytest---all-pytest"
    )
    assert github_anchor(" Fig 6.4: GCAS with M = 5 and 10") == "fig-64-gcas-with-m--5-and-10"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_resolves(page: Path) -> None:
    broken = []
    for target in LINK.findall(page.read_text(encoding="utf-8")):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto: ...
            continue
        file, _, fragment = target.partition("#")
        dest = (page.parent / file).resolve() if file else page
        if not dest.exists():
            broken.append(f"{target}: no such file")
        elif fragment and fragment not in anchors(dest):
            broken.append(f"{target}: no heading with that anchor in {dest.name}")
    assert broken == [], f"{page.name}: {broken}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_document_named_in_the_prose_exists(page: Path) -> None:
    named = set(re.findall(r"\bdocs/([a-z][a-z0-9-]*)\.md\b", page.read_text(encoding="utf-8")))
    shipped = {p.stem for p in (ROOT / "docs").glob("*.md")}
    assert named - shipped == set(), f"{page.name} names documents that do not exist"
