"""Data flows one way: the emulator never imports the driver; the driver never imports bench."""

from __future__ import annotations

import subprocess
import sys


def _modules_after(statement: str) -> set[str]:
    code = f"import sys; {statement}; print('\\n'.join(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return set(out.stdout.split())


def test_emulator_does_not_import_the_driver() -> None:
    mods = _modules_after("import fakes.arm, fakes.serve")
    assert "drivers.arm" not in mods
    assert not any(m.startswith(("bench", "reports")) for m in mods)


def test_driver_does_not_import_bench_reports_or_the_emulator() -> None:
    mods = _modules_after("import drivers.arm")
    assert not any(m.startswith(("bench", "reports", "fakes")) for m in mods)


def test_driver_names_are_exported_lazily() -> None:
    mods = _modules_after("import drivers; drivers.Arm")
    assert "drivers.arm" in mods
