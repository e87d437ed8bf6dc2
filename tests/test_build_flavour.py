"""The rule that picks the tests run against both builds (``build_flavour.py``): it sees an
import of a hot module however it is written, every hot module has tests it picks, and
``.ci/run``'s plain-Python stage runs what it picks."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from build_flavour import FLAVOUR_MODULES, concerns_the_build_flavour, imported_modules

import armbench
from armbench.cli.perf.hot_modules import HOT_MODULES

TESTS = Path(__file__).resolve().parent
CI = TESTS.parent / ".ci" / "run"


@pytest.mark.parametrize("source", [
    "import armbench.fakes.twin.joint\n",
    "import armbench.fakes.twin.joint as j\n",
    "from armbench.fakes.twin import joint\n",
    "from armbench.fakes.twin.joint import Motion\n",
    "def f() -> None:\n    from armbench.drivers.model.protocol import Command\n",
    "from helper_of_tests import thing\n",
])
def test_an_import_of_a_hot_module_is_seen_however_written(source: str, tmp_path: Path
                                                           ) -> None:
    (tmp_path / "helper_of_tests.py").write_text("from armbench.fakes.firmware import uart\n")
    module = tmp_path / "test_module.py"
    module.write_text(source)
    assert concerns_the_build_flavour(module)


@pytest.mark.parametrize("source", [
    "import armbench.fakes.twin\n",                       # the package, not a hot module in it
    "from armbench.drivers.model.settings import RobotSettings\n",
    "from .joint import Motion\n",                        # relative: not the package's module
    "from helper_of_tests import thing\n",
    "import numpy\n",
    "from test_other import a_fixture\n",                # borrowed from another test module
])
def test_other_imports_are_not(source: str, tmp_path: Path) -> None:
    (tmp_path / "helper_of_tests.py").write_text("from test_module import x\n")  # a cycle
    (tmp_path / "test_other.py").write_text("from armbench.fakes.firmware import uart\n")
    module = tmp_path / "test_module.py"
    module.write_text(source)
    assert not concerns_the_build_flavour(module)


def _source(module: str) -> str:
    """The Python source of an installed module of armbench, found from the package's own
    folder (a compiled module's sits beside it; its ``__file__`` may name mypyc's staging)."""
    root = Path(armbench.__file__).parent.parent  # as installed: not where a link leads
    return (root / f"{module.replace('.', '/')}.py").read_text(encoding="utf-8")


def test_every_hot_module_has_tests_run_against_both_builds() -> None:
    """Each hot module is imported by a picked test module, or by the emulator or a hot module
    a picked one imports (the emulator is made of the boards, the UART, the bus and the joints;
    a joint of its stepper and drive train)."""
    picked = [p for p in sorted(TESTS.glob("test_*.py")) if concerns_the_build_flavour(p)]
    reached = set().union(*(imported_modules(p.read_text(encoding="utf-8")) for p in picked))
    todo = reached & FLAVOUR_MODULES
    while todo:
        found = imported_modules(_source(todo.pop()))
        todo |= (found - reached) & FLAVOUR_MODULES
        reached |= found
    assert set(HOT_MODULES) <= reached, set(HOT_MODULES) - reached


def test_the_plain_python_stage_runs_the_picked_tests() -> None:
    """The stage installs the plain-Python build into a venv, then runs the tests the rule
    marks (not slow: the slow stage built and compared both wheels already) with that venv's
    Python, first on PATH."""
    stage = CI.read_text(encoding="utf-8").split('stage "tests against the plain-Python build')[1]
    install = re.search(r'^ *ARMBENCH_PURE_PYTHON=1 "(\$\w+)/bin/python" -m pip install', stage,
                        re.MULTILINE)
    assert install is not None, stage
    venv = re.escape(install.group(1))
    (command,) = re.findall(rf'^ *PATH="{venv}/bin:\$PATH" "{venv}/bin/python" -m pytest .*$',
                            stage, re.MULTILINE)
    assert "-m 'build_flavour and not slow'" in command, command
