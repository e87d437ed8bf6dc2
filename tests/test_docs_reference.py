"""The reference pages say what is: no date and no commit in them (dated runs belong in
``measurements/``, history in ``CHANGELOG.md``), and every page they, the README or the code name
exists. Read from the checkout's files, as a reader of the repository sees them."""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The reference: what the code does today.
REFERENCE = sorted([*(ROOT / "docs").glob("*.md"), ROOT / "README.md", ROOT / "fuzz" / "README.md",
                    ROOT / "measurements" / "README.md"])
#: Pages of history: they may hold dates and commits, and mention pages since merged or moved.
HISTORY = sorted([ROOT / "CHANGELOG.md", *(ROOT / "measurements").glob("*.md")])
#: Where code and configuration name docs pages (docstrings, error messages, comments).
CODE_FOLDERS = ("api", "cli", "frontends", "reports", "bench", "record", "metrics", "fakes",
                "drivers", "scripts", "tests", "fuzz", ".ci", ".github")
CODE_FILES = ("pyproject.toml", "setup.py", "tox.ini")
CODE_SUFFIXES = {".py", ".toml", ".ini", ".yml", ".yaml", ".j2", ".c", ".h", ""}

DATE = re.compile(r"\b20\d\d-[01]\d-[0-3]\d\b")
#: A commit hash in backticks: 7 to 40 hex digits with at least a letter and a digit among them
#: (so neither a number nor a word such as `decade` is taken for one).
COMMIT = re.compile(r"`(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])([0-9a-f]{7,40})`")
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
PAGE = re.compile(r"(?<![\w./-])((?:docs|measurements)/[\w.-]+\.md)\b")


def dated(text: str) -> list[str]:
    """Each date and each commit hash the text holds, with its line number."""
    found = []
    for n, line in enumerate(text.splitlines(), 1):
        found += [f"{n}: {m.group(0)}" for m in DATE.finditer(line)]
        found += [f"{n}: {m.group(0)}" for m in COMMIT.finditer(line)]
    return found


def broken_links(page: Path, text: str) -> list[str]:
    """Each relative Markdown link of the page whose file does not exist."""
    broken = []
    for m in LINK.finditer(text):
        target = m.group(1).split("#", 1)[0]
        if not target or re.match(r"[a-z][a-z0-9+.-]*:", target):
            continue  # an anchor in the page, or an address (https:, mailto:)
        if not (page.parent / target).exists():
            broken.append(m.group(1))
    return broken


def missing_pages(text: str) -> list[str]:
    """Each ``docs/...md`` or ``measurements/...md`` the text names that does not exist (a file
    name pattern such as ``measurements/YYYY-MM-DD-TOPIC.md`` names none)."""
    return sorted({m.group(1) for m in PAGE.finditer(text)
                   if "YYYY" not in m.group(1) and not (ROOT / m.group(1)).is_file()})


def _code_files() -> Iterator[Path]:
    yield from (ROOT / name for name in CODE_FILES)
    for folder in CODE_FOLDERS:
        for path in sorted((ROOT / folder).rglob("*")):
            if (path.is_file() and path.suffix in CODE_SUFFIXES and "__pycache__" not in path.parts
                    and path != Path(__file__).resolve()):
                yield path


def _read(paths: Iterable[Path]) -> Iterator[tuple[Path, str]]:
    for path in paths:
        try:
            yield path, path.read_text(encoding="utf-8")
        except (UnicodeDecodeError, FileNotFoundError):
            continue


def test_no_reference_page_holds_a_date_or_a_commit() -> None:
    found = {str(p.relative_to(ROOT)): d for p, text in _read(REFERENCE) if (d := dated(text))}
    assert found == {}, "dated runs go to measurements/ (scripts/measure.py), history to " \
                        "CHANGELOG.md"


def test_every_relative_link_between_pages_resolves() -> None:
    broken = {str(p.relative_to(ROOT)): b for p, text in _read([*REFERENCE, *HISTORY])
              if (b := broken_links(p, text))}
    assert broken == {}


def test_every_page_the_reference_and_the_code_name_exists() -> None:
    missing = {str(p.relative_to(ROOT)): m for p, text in _read([*REFERENCE, *_code_files()])
               if (m := missing_pages(text))}
    assert missing == {}


def test_the_checks_find_a_date_a_commit_a_broken_link_and_a_missing_page(tmp_path: Path) -> None:
    assert dated("measured 2026-11-24 on `a1b2c3d`") == ["1: 2026-11-24", "1: `a1b2c3d`"]
    assert dated("`1048576` bytes, the `decade`, `deadbeef`, version 2.4.1") == []
    page = tmp_path / "page.md"
    (tmp_path / "there.md").write_text("", encoding="utf-8")
    text = "[a](there.md#x) [b](gone.md) [c](https://example.org/x.md) [d](#top)"
    assert broken_links(page, text) == ["gone.md"]
    assert missing_pages("see `docs/architecture.md` and docs/no-such-page.md.") == [
        "docs/no-such-page.md"]
