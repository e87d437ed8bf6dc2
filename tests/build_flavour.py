"""Which test modules the build flavour concerns: a release wheel and a plain-Python one
(``ARMBENCH_PURE_PYTHON=1``) differ only in the hot modules (``cli/perf/hot_modules.py``),
compiled by mypyc in one and their Python source in the other. A test module that imports a hot
module or the emulator they make up (:data:`FLAVOUR_MODULES`), itself or through a helper module
of ``tests/``, tests that code directly: it is run against both builds (``.ci/run``'s
plain-Python stage runs ``-m build_flavour``). A test module that borrows a fixture or a helper
from another test module (``from test_runner import ...``) is not a test of what that one
tests: the import is not followed. The rest of the suite reaches the hot modules only through
the same calls, which the slow stage compares between the two builds call by call
(``test_compiled_equal.py``) and session by session (``test_compiled.py``)."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

from armbench.cli.perf.hot_modules import HOT_MODULES

#: The hot modules, and the emulator put together from them (its boards, UART, bus, joints).
FLAVOUR_MODULES = frozenset({*HOT_MODULES, "armbench.fakes.firmware.arm_emulator"})


def imported_modules(source: str) -> set[str]:
    """Every module an ``import`` anywhere in ``source`` names (at module level or inside a
    function), and for ``from P import n`` both ``P`` and ``P.n`` (``n`` may be a module)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module)
            names.update(f"{node.module}.{a.name}" for a in node.names)
    return names


@functools.cache
def concerns_the_build_flavour(path: Path) -> bool:
    """Whether the module at ``path`` imports one of :data:`FLAVOUR_MODULES`, itself or through
    the helper modules of its folder it imports (``build_trace``, ...; not another
    ``test_*`` module, whose fixtures and helpers it merely borrows)."""
    return _reaches_a_flavour_module(path, set())


def _reaches_a_flavour_module(path: Path, seen: set[Path]) -> bool:
    seen.add(path)
    names = imported_modules(path.read_text(encoding="utf-8"))
    if names & FLAVOUR_MODULES:
        return True
    helpers = (path.parent / f"{name}.py" for name in names
               if "." not in name and not name.startswith("test_"))
    return any(helper.is_file() and helper not in seen and _reaches_a_flavour_module(helper, seen)
               for helper in helpers)
