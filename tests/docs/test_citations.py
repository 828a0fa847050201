"""Every place the code and the reference pages cite a docs page by section ('docs/diagnosis.md, "Known limits"',
'docs/reference.md, section 2') names a section that page has: a heading, or a paragraph's bold run-in title
('**Which rule.**'). The history pages are left out as sources: they cite the pages as they were."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CITE = re.compile(r'(docs/[\w/]+\.md),?\s+(?:"([^"]+)"|section (\d+))')
CONTINUATION = re.compile(r"\s*\n\s*(?:#:?\s|\*\s|>\s)?\s*")  # a citation wrapped over lines of a comment or list
JOINED = re.compile(r'"\s*\n\s*[rf]*"')  # ... or over two string literals that Python joins


def sections(page: Path) -> list[str]:
    out, fence = [], False
    for line in page.read_text().splitlines():
        if line.lstrip().startswith("```"):
            fence = not fence
        elif not fence:
            m = re.match(r"^#{1,6} (.*)$", line)
            out += [m.group(1).strip()] if m else [b.strip().rstrip(".:") for b in re.findall(r"\*\*([^*]+)\*\*", line)]
    return [s.replace("``", "`") for s in out]


def names(title: str, cited: str) -> bool:
    """Whether a section ``title`` is the ``cited`` one: the same, or the cited words and then a colon or bracket;
    a section's number ('8. The valve file') and code quotes around a name are not part of it."""
    title, cited = (re.sub(r"^\d+\.\s+", "", v).replace("`", "") for v in (title, cited))
    return title == cited or re.match(re.escape(cited) + r"(\s*[:(,]| and )", title) is not None


def sources() -> list[Path]:
    code = [p for d in ("valve_env", "agents", "studies", "benchmarks", "tests") for p in (ROOT / d).rglob("*.py")]
    pages = [p for p in (ROOT / "docs").rglob("*.md") if "history" not in p.parts]
    return sorted([*code, *pages, ROOT / "README.md"])


def citations() -> list[tuple[str, str, str]]:
    out = []
    for src in sources():
        text = CONTINUATION.sub(" ", JOINED.sub("", src.read_text()))
        for m in CITE.finditer(text):
            page, title, number = m.groups()
            out.append((str(src.relative_to(ROOT)), page, title.replace("``", "`") if title else f"section {number}"))
    return sorted(set(out))


CITATIONS = citations()


def test_the_citations_are_found() -> None:
    # the pattern finds the project's citations at all (a broken pattern would pass every check below)
    assert len(CITATIONS) > 100
    assert any(page == "docs/reference.md" and cited == "section 2" for _, page, cited in CITATIONS)


@pytest.mark.parametrize("source,page,cited", CITATIONS, ids=lambda v: str(v)[:60])
def test_a_cited_section_exists(source: str, page: str, cited: str) -> None:
    path = ROOT / page
    assert path.is_file(), f"{source} cites {page}, which does not exist"
    titles = sections(path)
    if cited.startswith("section "):
        number = cited.split()[1]
        assert any(re.match(rf"{number}\.\s", t) for t in titles), f"{source} cites {page}, {cited}: no such section"
    else:
        assert any(names(t, cited) for t in titles), f"{source} cites {page}, {cited!r}: no such section"
