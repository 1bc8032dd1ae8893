"""The docs as a reference: every page short enough to read, every page the project names exists, and a section
named after a page (``docs/validation-closed-forms.md, Viscous substeps``) is a heading or bold label of that page."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
MAX_LINES = 300
#: The files that name docs pages: the README, the docs themselves, the package, its configs, scripts and tests.
SOURCES = ("README.md", "docs/*.md", "docs/data/**/README.md", "diffstir/**/*.py", "conf/**/*.yaml", "scripts/*",
           "tests/**/*.py", "checkpoints/**/*.md", "pyproject.toml")
#: ``docs/<page>.md`` and, after a comma, what may name one of its sections (up to ``)``, ``;``, a sentence's end).
REFERENCE = re.compile(r"docs/([a-z0-9-]+)\.md`?(?:,\s+([^;)\n]+?)(?=[;)\n]|\.\s|\.$|$))?")


def pages() -> list[Path]:
    return sorted(DOCS.glob("*.md"))


def references() -> list[tuple[str, str, str | None]]:
    """(where, page, section or None) for every docs page named in the project's files."""
    found = []
    for pattern in SOURCES:
        for path in sorted(ROOT.glob(pattern)):
            if not path.is_file():
                continue
            text = path.read_text(encoding="utf-8")
            for match in REFERENCE.finditer(text):
                where = f"{path.relative_to(ROOT)}:{text[:match.start()].count(chr(10)) + 1}"
                found.append((where, match.group(1), match.group(2)))
    return found


def labels(page: Path) -> list[str]:
    """A page's headings and bold labels, lower case, without a trailing full stop or colon."""
    text = page.read_text(encoding="utf-8")
    heads = [re.sub(r"^#+\s*", "", line) for line in text.splitlines() if line.startswith("#")]
    bold = re.findall(r"\*\*([^*]+?)\*\*", text)
    return [label.strip().rstrip(".:").lower() for label in heads + bold if label.strip()]


def section_name(text: str | None) -> str | None:
    """What a reference names as a section: a title (capitalised, possibly quoted), not a phrase, a step number or
    another path."""
    if text is None:
        return None
    name = text.strip().strip("\"'`").rstrip(".").strip()
    if not name[:1].isupper() or name.startswith(("docs/", "scripts/")) or re.match(r"[Ss]tep \d", name):
        return None
    return name.lower()


@pytest.mark.parametrize("page", pages(), ids=lambda p: p.name)
def test_every_page_is_at_most_300_lines(page):
    lines = page.read_text(encoding="utf-8").count("\n")
    assert lines <= MAX_LINES, f"{page.relative_to(ROOT)}: {lines} lines; split it by topic (at most {MAX_LINES})"


def test_every_named_page_exists():
    missing = [f"{where}: docs/{page}.md" for where, page, _ in references() if not (DOCS / f"{page}.md").exists()]
    assert not missing, "\n".join(missing)


def test_every_named_section_is_on_its_page():
    known = {page.stem: labels(page) for page in pages()}
    missing = []
    for where, page, text in references():
        name = section_name(text)
        if name is None or page not in known:
            continue
        if not any(label.startswith(name) or name.startswith(label) for label in known[page]):
            missing.append(f"{where}: docs/{page}.md, {text.strip()}")
    assert not missing, "\n".join(missing)
