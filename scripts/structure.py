"""The package's import graph as pydeps sees it: one connected piece, no import running up.

pydeps reads the import statements of the installed package's bytecode (all of them: also those
under ``if TYPE_CHECKING:``, which import-linter and the grimp tests leave out), so it is a second,
independent reading of the structure that ``tests/test_architecture.py`` checks with grimp. This
script runs it over the installed ``armbench`` (a regular install or a strict-mode editable one,
which lays the package out as a tree), or reads a ``--deps-output`` file it wrote, and checks:

- every module is reachable from every other along imports, either way;
- no import goes from a layer of one of pyproject.toml's ``layers`` contracts (the package's, and
  each folder's) to a layer above it.

It prints the figures (modules, edges, components, upward edges) and exits 1 on a violation::

    python scripts/structure.py [--deps FILE.json] [--pyproject pyproject.toml]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import subprocess
import sys
import tempfile
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
Graph = Mapping[str, Sequence[str]]


@dataclass(frozen=True, slots=True)
class Structure:
    """What the check found: the modules, the import edges, the connected pieces (largest
    first) and the imports that run from a layer up to a higher one."""

    modules: int
    edges: int
    components: list[list[str]]
    upward: list[tuple[str, str]]
    unplaced: list[str]

    def problems(self) -> list[str]:
        """One line per violation: a piece beside the main one, an upward import, a module in
        no layer."""
        out = [f"not connected to the rest: {', '.join(c)}" for c in self.components[1:]]
        out += [f"imports up: {a} -> {b}" for a, b in self.upward]
        out += [f"in no layer: {m}" for m in self.unplaced]
        return out


def layers(pyproject: Path) -> list[list[list[str]]]:
    """The orders of pyproject.toml's ``layers`` import-linter contracts, each top first and
    fully named: the package's own (the one without containers) first, then each folder's."""
    config = tomllib.loads(pyproject.read_text(encoding="utf-8"))
    contracts = [c for c in config["tool"]["importlinter"]["contracts"] if c["type"] == "layers"]
    tops = [c for c in contracts if not c.get("containers")]
    if len(tops) != 1:
        raise ValueError(f"{pyproject}: {len(tops)} layers contracts without containers, "
                         "expected one (the package's own)")

    def order(contract: Mapping[str, Any], prefix: str) -> list[list[str]]:
        return [[prefix + m.strip() for m in layer.replace("|", ":").split(":")]
                for layer in contract["layers"]]

    return [order(tops[0], "")] + [order(c, container + ".") for c in contracts
                                   if c.get("containers") for container in c["containers"]]


def layer_of(module: str, order: Sequence[Sequence[str]]) -> int | None:
    for index, layer in enumerate(order):
        if any(module == m or module.startswith(m + ".") for m in layer):
            return index
    return None


def graph_of(deps: Mapping[str, Any], package: str = "armbench") -> dict[str, list[str]]:
    """The package's modules and what each imports among them, from pydeps' JSON."""
    mods = {name for name in deps if name == package or name.startswith(package + ".")}
    return {name: sorted(i for i in deps[name].get("imports", []) if i in mods and i != name)
            for name in sorted(mods)}


def examine(graph: Graph, orders: Sequence[Sequence[Sequence[str]]],
            outside: frozenset[str] = frozenset({"armbench", "armbench.cli.perf.hot_modules"}),
            ) -> Structure:
    """The figures and violations of ``graph`` against the layer ``orders`` (each top first;
    the first the package's own, which every module must be placed in);
    ``outside``: modules no layer holds (the root package's lazy public names, the build's list
    of compiled modules), as in ``tests/test_architecture.py``."""
    edges = {(a, b) for a, imported in graph.items() for b in imported}
    neighbours: dict[str, set[str]] = {m: set() for m in graph}
    for a, b in edges:
        neighbours[a].add(b)
        neighbours[b].add(a)
    seen: set[str] = set()
    components: list[list[str]] = []
    for start in sorted(graph):
        if start in seen:
            continue
        piece, todo = {start}, [start]
        seen.add(start)
        while todo:
            for n in neighbours[todo.pop()] - seen:
                seen.add(n)
                piece.add(n)
                todo.append(n)
        components.append(sorted(piece))
    components.sort(key=lambda c: (-len(c), c))
    upward = sorted({(a, b) for order in orders for a, b in edges
                     if (low := layer_of(a, order)) is not None
                     and (high := layer_of(b, order)) is not None and high < low})
    unplaced = sorted(m for m in graph if m not in outside and layer_of(m, orders[0]) is None
                      and not (graph[m] == [] and _is_package_of(m, graph)))
    return Structure(len(graph), len(edges), components, upward, unplaced)


def _is_package_of(module: str, graph: Graph) -> bool:
    """Whether ``module`` is a package (other modules live under it): one that imports nothing
    needs no layer (``drivers/__init__``)."""
    return any(m.startswith(module + ".") for m in graph)


def run_pydeps(out: Path) -> None:
    """pydeps over the sources of the installed armbench, its JSON into ``out`` (no graphviz
    needed)."""
    import armbench

    tree = Path(next(iter(armbench.__path__)))
    if not (tree / "bench").is_dir():
        raise SystemExit("armbench is installed with an import hook: pydeps needs pip install . "
                         "or pip install -e . --config-settings editable_mode=strict")
    if importlib.util.find_spec("pydeps") is None:
        raise SystemExit("pydeps is not installed (pip install pydeps)")
    with tempfile.TemporaryDirectory() as tmp:
        # a release build's compiled modules sit beside their sources and are found first, and
        # an extension module's imports cannot be read: pydeps reads a copy without them
        sources = Path(tmp) / "armbench"
        shutil.copytree(tree, sources, ignore=shutil.ignore_patterns(
            "*.so", "*.pyd", "__pycache__"))
        subprocess.run([sys.executable, "-m", "pydeps", str(sources), "--show-deps",
                        "--no-output", "--max-bacon", "0", "--only", "armbench",
                        "--deps-output", str(out)],
                       check=True, stdout=subprocess.DEVNULL, timeout=600, cwd=tmp)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--deps", type=Path, help="pydeps' --deps-output JSON (default: run it)")
    parser.add_argument("--pyproject", type=Path, default=ROOT / "pyproject.toml")
    args = parser.parse_args(argv)
    if args.deps is None:
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "deps.json"
            run_pydeps(path)
            deps = json.loads(path.read_text(encoding="utf-8"))
    else:
        deps = json.loads(args.deps.read_text(encoding="utf-8"))
    found = examine(graph_of(deps), layers(args.pyproject))
    print(f"modules {found.modules}, edges {found.edges}, components {len(found.components)}, "
          f"upward edges {len(found.upward)}")
    problems = found.problems()
    for line in problems:
        print(line)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
