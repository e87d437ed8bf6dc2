"""The house's rules, checked on the code itself: the import contracts of pyproject.toml
(import-linter), no import cycle among modules, rooms of at most 600 lines. ruff and mypy --strict
run as steps of their own (``tox -e lint``, ``tox -e type``, ``.ci/run``).

The import graph is read from the package as installed: a regular install, or an editable one in
strict mode (``setup.py``), which lays the package out as a tree; the default editable mode maps
the folders with an import hook that static tools cannot follow."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import grimp
import pytest

import armbench

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("bench", "capture", "cli", "drivers", "fakes", "metrics", "record", "reports")
#: Rooms of one job are about 500 lines; none may pass this.
MAX_LINES = 600


@pytest.fixture
def laid_out() -> None:
    """Skip where the installed package is not a tree static tools can walk."""
    if not all((Path(p) / "bench").is_dir() for p in armbench.__path__):
        pytest.skip("armbench is installed in editable mode with an import hook: static tools "
                    "need pip install . or pip install -e . --config-settings editable_mode=strict")


@pytest.mark.usefixtures("laid_out")
def test_import_contracts_hold() -> None:
    code = "from importlinter.cli import lint_imports_command; lint_imports_command()"
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "0 broken" in done.stdout


def _cycles(adjacency: dict[str, list[str]]) -> Iterator[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    for root in adjacency:
        if root in index:
            continue
        work = [(root, iter(adjacency[root]))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, successors = work[-1]
            nxt = next(successors, None)
            if nxt is not None:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(adjacency[nxt])))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    yield sorted(component)


def test_cycle_finder_finds_a_cycle() -> None:
    assert list(_cycles({"a": ["b"], "b": ["c"], "c": ["a"], "d": ["a"]})) == [["a", "b", "c"]]


@pytest.mark.usefixtures("laid_out")
def test_no_import_cycle_among_modules() -> None:
    graph = grimp.build_graph("armbench", exclude_type_checking_imports=True)
    adjacency = {m: sorted(i for i in graph.find_modules_directly_imported_by(m)
                           if i in graph.modules) for m in sorted(graph.modules)}
    assert list(_cycles(adjacency)) == []


@pytest.mark.parametrize("package", PACKAGES)
def test_rooms_of_one_job(package: str) -> None:
    too_long = {str(p.relative_to(ROOT)): n for p in (ROOT / package).rglob("*.py")
                if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert too_long == {}
