"""The house read by folders: every folder of the package is a node, and an import from a module
of one folder to a module of another is an edge (every import statement counts: those only for
type checking, and those inside functions). The folders must form the layers pyproject.toml
declares (the top layers contract, then one contract per folder of folders): no edge runs up or
sideways, no circle exists at any level, parent and child included, and every folder is placed.

Read from the checkout's sources, so the figures describe what is committed; the import
contracts and grimp's module graph (``tests/test_architecture.py``) read the installed package.
"""

from __future__ import annotations

import ast
import tomllib
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Checkout folder of each top package (setup.py's mapping); ``api/`` is ``armbench`` itself.
TOP_FOLDERS = {"armbench": "api", **{f"armbench.{n}": n for n in (
    "bench", "cli", "drivers", "fakes", "frontends", "metrics", "record", "reports")}}
#: No folder may hold more than this share of the package's lines (a folder doing one job).
MAX_FOLDER_SHARE = 0.12


@dataclass(frozen=True)
class Source:
    """The package's modules (dotted name to file) and the package each belongs to."""

    files: dict[str, Path]
    package: dict[str, str]


def read_sources() -> Source:
    files: dict[str, Path] = {}
    package: dict[str, str] = {}
    for pkg, folder in TOP_FOLDERS.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            parts = list(path.relative_to(ROOT / folder).with_suffix("").parts)
            is_init = parts[-1] == "__init__"
            if is_init:
                parts = parts[:-1]
            name = ".".join([pkg, *parts])
            files[name] = path
            package[name] = name if is_init else name.rsplit(".", 1)[0]
    return Source(files, package)


def _imported(module: str, path: Path, is_package: bool) -> set[str]:
    """Every ``armbench`` name an import statement of the module names, at any depth."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")[: None if is_package else -1]
                base = base[: len(base) - node.level + 1]
                origin = ".".join([*base, *([node.module] if node.module else [])])
            else:
                origin = node.module or ""
            found.add(origin)
            found.update(f"{origin}.{a.name}" for a in node.names)
    return {n for n in found if n == "armbench" or n.startswith("armbench.")}


def folder_edges(source: Source) -> dict[tuple[str, str], list[str]]:
    """Each edge between two folders, with the imports (``module -> module``) behind it."""
    edges: dict[tuple[str, str], list[str]] = defaultdict(list)
    for module, path in source.files.items():
        is_package = path.name == "__init__.py"
        for name in _imported(module, path, is_package):
            target = name
            while target not in source.files and "." in target:
                target = target.rsplit(".", 1)[0]
            if target not in source.files or target == module:
                continue
            a, b = source.package[module], source.package[target]
            if a != b:
                edges[(a, b)].append(f"{module} -> {target}")
    return edges


@dataclass(frozen=True)
class Layers:
    """pyproject.toml's layers: the top packages in order, and each container's folders."""

    top: list[list[str]]
    inner: dict[str, list[list[str]]]

    def rank(self, package: str) -> tuple[int, str | None, int]:
        """(top layer, container, layer in the container) of a package; -1 where it has none."""
        top = next((i for i, layer in enumerate(self.top)
                    if any(package == p or package.startswith(p + ".") for p in layer)), -1)
        for container, layers in self.inner.items():
            if package.startswith(container + "."):
                child = package[len(container) + 1:].split(".")[0]
                inner = next((i for i, layer in enumerate(layers) if child in layer), -1)
                return top, container, inner
        return top, None, -1

    def allows(self, a: str, b: str) -> bool:
        """May a module of package ``a`` import one of package ``b``?"""
        if b == "armbench":
            return False
        if a == "armbench":
            return True
        (top_a, box_a, in_a), (top_b, box_b, in_b) = self.rank(a), self.rank(b)
        if top_a != top_b:
            return top_a < top_b
        if b.startswith(a + "."):
            return True  # a folder's __init__ exports its children
        return box_a is not None and box_a == box_b and 0 <= in_a < in_b


def read_layers() -> Layers:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    top: list[list[str]] = []
    inner: dict[str, list[list[str]]] = {}
    for contract in config["tool"]["importlinter"]["contracts"]:
        def split(layer: str) -> list[str]:
            return [m.strip() for m in layer.replace("|", ":").split(":")]
        if contract["type"] == "layers" and "containers" not in contract:
            top = [split(layer) for layer in contract["layers"]]
        elif contract["type"] == "layers":
            for container in contract["containers"]:
                inner[container] = [split(layer) for layer in contract["layers"]]
        elif contract["type"] == "independence":
            modules = contract["modules"]
            container = modules[0].rsplit(".", 1)[0]
            if all(m.rsplit(".", 1)[0] == container for m in modules):
                inner[container] = [[m.rsplit(".", 1)[1] for m in modules]]
    return Layers(top, inner)


def find_cycle(nodes: set[str], edges: set[tuple[str, str]]) -> list[str]:
    """One circle of the graph, as its nodes in order, or [] when there is none."""
    out: dict[str, list[str]] = defaultdict(list)
    for a, b in edges:
        out[a].append(b)
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str]:
        state[n] = 1
        stack.append(n)
        for m in sorted(out[n]):
            if state.get(m) == 1:
                return [*stack[stack.index(m):], m]
            if m not in state and (found := visit(m)):
                return found
        stack.pop()
        state[n] = 2
        return []

    for n in sorted(nodes):
        if n not in state and (found := visit(n)):
            return found
    return []


@pytest.fixture(scope="module")
def source() -> Source:
    return read_sources()


def test_the_folder_graph_has_no_circle(source: Source) -> None:
    edges = folder_edges(source)
    assert find_cycle(set(source.package.values()), set(edges)) == []


def test_no_import_between_folders_runs_up_or_sideways(source: Source) -> None:
    layers = read_layers()
    wrong = {f"{a} -> {b}": why[:3] for (a, b), why in folder_edges(source).items()
             if not layers.allows(a, b)}
    assert wrong == {}


def test_every_folder_is_placed(source: Source) -> None:
    """A new folder is declared in a layer; a folder that holds folders is a container."""
    layers = read_layers()
    packages = set(source.package.values()) - {"armbench"}
    unplaced = sorted(p for p in packages if layers.rank(p)[0] < 0)
    parents = {p.rsplit(".", 1)[0] for p in packages if p.count(".") >= 2}
    undeclared = sorted(p for p in parents if p not in layers.inner)
    inside = sorted(p for p in packages
                    if (r := layers.rank(p))[1] is not None and r[2] < 0)
    assert (unplaced, undeclared, inside) == ([], [], [])


def test_a_folder_of_folders_holds_no_modules_of_its_own(source: Source) -> None:
    """A folder either holds modules (one job) or folders (its layers), never both: a module
    beside the layers would belong to none. The command line's entry, ``cli/main.py``, is the
    one layer that is a module (pyproject.toml places it)."""
    layers = read_layers()
    beside = sorted(m for m, p in source.package.items()
                    if p in layers.inner and m != p
                    and m.rsplit(".", 1)[1] not in {n for layer in layers.inner[p] for n in layer})
    assert beside == []


def test_no_folder_holds_more_than_an_eighth_of_the_lines(source: Source) -> None:
    lines: dict[str, int] = defaultdict(int)
    for module, path in source.files.items():
        lines[source.package[module]] += len(path.read_text(encoding="utf-8").splitlines())
    total = sum(lines.values())
    largest = max(lines, key=lambda p: lines[p])
    assert lines[largest] / total <= MAX_FOLDER_SHARE, (largest, lines[largest], total)


def test_the_check_finds_a_circle_an_upward_edge_and_a_sideways_one() -> None:
    assert find_cycle({"a", "b", "c"}, {("a", "b"), ("b", "c"), ("c", "a")}) == \
        ["a", "b", "c", "a"]
    assert find_cycle({"a", "b"}, {("a", "b")}) == []
    layers = Layers(top=[["armbench.cli"], ["armbench.bench"], ["armbench.drivers"]],
                    inner={"armbench.bench": [["campaign", "twin_check"], ["runner"]]})
    assert layers.allows("armbench.cli", "armbench.bench.runner")
    assert not layers.allows("armbench.drivers", "armbench.bench")
    assert layers.allows("armbench.bench.campaign", "armbench.bench.runner")
    assert not layers.allows("armbench.bench.runner", "armbench.bench.campaign")
    assert not layers.allows("armbench.bench.campaign", "armbench.bench.twin_check")
    assert not layers.allows("armbench.bench.runner", "armbench.bench")
    assert layers.allows("armbench.bench", "armbench.bench.runner")
