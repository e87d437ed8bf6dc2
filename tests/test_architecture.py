"""The house's rules, checked on the code itself: the import contracts of pyproject.toml
(import-linter), no import cycle among modules, rooms of at most 600 lines, and the same layers
and one connected graph as pydeps reads them (``scripts/structure.py``, ``tox -e structure``).
ruff and mypy --strict run as steps of their own (``tox -e lint``, ``tox -e type``,
``.ci/run``).

The import graph is read from the package as installed: a regular install, or an editable one in
strict mode (``setup.py``), which lays the package out as a tree; the default editable mode maps
the folders with an import hook that static tools cannot follow."""

from __future__ import annotations

import importlib.util
import pkgutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import grimp
import pytest
from script_loader import load_script

import armbench

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("bench", "cli", "drivers", "fakes", "frontends", "metrics", "record", "reports")
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
    graph = grimp.build_graph("armbench", exclude_type_checking_imports=False)
    adjacency = {m: sorted(i for i in graph.find_modules_directly_imported_by(m)
                           if i in graph.modules) for m in sorted(graph.modules)}
    assert list(_cycles(adjacency)) == []


@pytest.mark.parametrize("package", PACKAGES)
def test_rooms_of_one_job(package: str) -> None:
    too_long = {str(p.relative_to(ROOT)): n for p in (ROOT / package).rglob("*.py")
                if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert too_long == {}


def _layers() -> list[list[str]]:
    """The packages of each layer of pyproject.toml's top layers contract, top first."""
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    contracts = [c for c in config["tool"]["importlinter"]["contracts"]
                 if c["type"] == "layers" and "containers" not in c]
    assert len(contracts) == 1, "one top layers contract, from the command line down"
    return [[m.strip() for m in layer.replace("|", ":").split(":")]
            for layer in contracts[0]["layers"]]


def _layer_of(module: str, layers: list[list[str]]) -> int | None:
    for index, layer in enumerate(layers):
        if any(module == m or module.startswith(m + ".") for m in layer):
            return index
    return None


def test_the_layers_run_from_the_command_line_down_to_the_model() -> None:
    layers = _layers()
    order = [_layer_of(m, layers) for m in (
        "armbench.__main__", "armbench.cli.main", "armbench.frontends.ros2_node.node",
        "armbench.reports.pages.page", "armbench.bench.runner",
        "armbench.record.run_record", "armbench.metrics.iso9283",
        "armbench.fakes.firmware.arm_emulator", "armbench.drivers.host.arm",
        "armbench.drivers.model.errors")]
    placed = [index for index in order if index is not None]
    assert placed == sorted(placed) and len(placed) == len(order), order
    assert placed[0] == 0 and placed[-1] == len(layers) - 1


@pytest.mark.usefixtures("laid_out")
def test_every_module_has_a_layer_and_no_import_runs_up() -> None:
    """A new module is placed in a layer (pyproject.toml), and grimp's graph, read independently
    of import-linter, has no edge from a layer to one above it."""
    layers = _layers()
    graph = grimp.build_graph("armbench", exclude_type_checking_imports=False)
    # the root package (the public API's lazy names) and the build's list of compiled modules
    outside = {"armbench", "armbench.cli.perf.hot_modules"}
    unplaced = sorted(m for m in graph.modules if m not in outside and _layer_of(m, layers) is None
                      and m != "armbench.drivers")  # drivers/__init__ imports nothing
    assert unplaced == []
    upward = sorted(
        (m, i) for m in graph.modules for i in graph.find_modules_directly_imported_by(m)
        if (low := _layer_of(m, layers)) is not None
        and (high := _layer_of(i, layers)) is not None and high < low)
    assert upward == []


@pytest.mark.usefixtures("laid_out")
def test_the_import_graph_is_one_piece() -> None:
    """Every module is reachable from every other along imports (either way), but the package
    ``__init__`` modules that import nothing. The pytest plugin, which pytest loads by its entry
    point and which loads the fixtures by name, is reached from the fixtures (they read its
    options' names)."""
    graph = grimp.build_graph("armbench", exclude_type_checking_imports=False)
    neighbours: dict[str, set[str]] = {m: set() for m in graph.modules}
    for m in graph.modules:
        for i in graph.find_modules_directly_imported_by(m):
            neighbours[m].add(i)
            neighbours[i].add(m)
    start = "armbench.cli.main"
    seen, todo = {start}, [start]
    while todo:
        for n in neighbours[todo.pop()] - seen:
            seen.add(n)
            todo.append(n)
    packages = {m for m in graph.modules
                if any((Path(p) / (m.split(".", 1)[1].replace(".", "/") if "." in m else "")
                        / "__init__.py").is_file() for p in armbench.__path__)}
    assert sorted(graph.modules - seen - packages) == []


@pytest.mark.parametrize("package", PACKAGES)
def test_a_folder_imported_by_its_bare_name_is_refused(package: str) -> None:
    code = f"import sys; sys.path.insert(0, {str(ROOT)!r}); import {package}"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode != 0
    assert f"installs as armbench.{package}: import it by that name" in done.stderr


def _structure_script() -> ModuleType:
    return load_script("structure")


def test_the_structure_check_finds_a_piece_apart_and_an_import_up() -> None:
    """``scripts/structure.py``'s reading of a pydeps graph: a module nothing connects and an
    import from a layer to one above it are both reported."""
    structure = _structure_script()
    orders = [[["armbench.cli"], ["armbench.bench"], ["armbench.record"]],
              [["armbench.bench.run"], ["armbench.bench.suites"]]]
    deps = {
        "armbench.cli.main": {"imports": ["armbench.bench.run", "json"]},
        "armbench.bench.run": {"imports": ["armbench.record.io", "armbench.bench.suites"]},
        "armbench.bench.suites": {"imports": ["armbench.bench.run"]},  # up inside bench
        "armbench.record.io": {"imports": ["armbench.bench.run"]},  # up: record -> bench
        "armbench.record.lonely": {"imports": []},
        "numpy": {"imports": []},
    }
    found = structure.examine(structure.graph_of(deps), orders)
    assert (found.modules, found.edges) == (5, 5)
    assert found.components == [["armbench.bench.run", "armbench.bench.suites",
                                 "armbench.cli.main", "armbench.record.io"],
                                ["armbench.record.lonely"]]
    assert found.problems() == ["not connected to the rest: armbench.record.lonely",
                                "imports up: armbench.bench.suites -> armbench.bench.run",
                                "imports up: armbench.record.io -> armbench.bench.run"]


@pytest.mark.slow
@pytest.mark.usefixtures("laid_out")
def test_pydeps_sees_one_piece_and_no_import_up() -> None:
    """pydeps, reading every import statement (also those only for type checking), sees the
    layers of pyproject.toml hold and the modules form one piece."""
    if importlib.util.find_spec("pydeps") is None:
        pytest.skip("pydeps is not installed (pip install pydeps, or the test extra)")
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "structure.py")],
                          capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "components 1," in done.stdout and "upward edges 0" in done.stdout


@pytest.mark.parametrize("package", ["armbench", "armbench.bench.runner"])
def test_no_name_loaded_on_first_use_is_also_a_submodule(package: str) -> None:
    """A package whose names load on first use (its ``_LAZY``) must not export a name that is
    also one of its modules': once that module is imported (by any other), the package's
    attribute is the module, and ``from package import name`` gives it instead of the object."""
    pkg = importlib.import_module(package)
    lazy = set(pkg._LAZY)
    assert lazy <= set(pkg.__all__)
    submodules = {info.name for info in pkgutil.iter_modules(pkg.__path__)}
    assert lazy & submodules == set()
