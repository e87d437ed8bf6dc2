"""Data flows one way: the emulator never imports the driver; the driver never imports bench."""

from __future__ import annotations

import subprocess
import sys


def _modules_after(statement: str) -> set[str]:
    code = f"import sys; {statement}; print('\\n'.join(sorted(sys.modules)))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return set(out.stdout.split())


def test_emulator_does_not_import_the_driver() -> None:
    mods = _modules_after("import armbench.fakes.firmware.arm_emulator, "
                          "armbench.fakes.links.serve, armbench.fakes.links.fake_transport")
    assert "armbench.drivers.host.arm" not in mods
    assert not any(m.startswith(("armbench.bench", "armbench.reports")) for m in mods)


def test_driver_does_not_import_bench_reports_or_the_emulator() -> None:
    mods = _modules_after("import armbench.drivers.host.arm")
    assert not any(m.startswith(("armbench.bench", "armbench.reports", "armbench.fakes"))
                   for m in mods)


def test_the_packages_import_nothing_by_themselves() -> None:
    """``armbench`` and the packages the emulator and the driver share are light: importing them
    imports no driver, no numpy and no emulator module."""
    mods = _modules_after("import armbench, armbench.drivers, armbench.fakes, armbench.bench")
    assert not any(m.startswith(("armbench.drivers.host.arm", "armbench.fakes.", "numpy"))
                   for m in mods), sorted(mods)


def test_driver_names_are_exported_lazily() -> None:
    mods = _modules_after("import armbench; armbench.Arm; armbench.connect")
    assert "armbench.drivers.host.arm" in mods


def test_the_driver_reaches_the_fake_transport_only_by_name() -> None:
    """Choosing and opening transports other than ``fake://`` imports nothing of the emulator;
    ``fake://`` imports it through the registry's name."""
    mods = _modules_after("from armbench.drivers.transports import open_transport as o; "
                          "o('socket://127.0.0.1:9'); o('rfc2217://127.0.0.1:9'); o('/dev/null')")
    assert not any(m.startswith("armbench.fakes") for m in mods), sorted(mods)
    mods = _modules_after("from armbench.drivers.transports import open_transport as o; "
                          "o('fake://')")
    assert "armbench.fakes.links.fake_transport" in mods


def test_the_runner_writes_records_and_renders_nothing() -> None:
    """The runner imports no report code; ``cli.reporting`` (the run command's and the pytest
    plugin's) imports it only when a report is written."""
    mods = _modules_after("import armbench.bench.runner, armbench.cli.commands.run_files")
    assert not any(m.startswith("armbench.reports") for m in mods), sorted(mods)


def test_the_worker_processes_import_nothing_of_the_runner() -> None:
    """No cycle between the runner and its worker processes: ``bench.workers`` only runs jobs."""
    mods = _modules_after("import armbench.bench.workers.worker_process")
    assert not any(m.startswith("armbench.bench.runner") for m in mods), sorted(mods)


def test_finding_the_suites_contracts_imports_no_suite() -> None:
    """The contracts' registry, which record readers and the report use, imports the light
    ``*_contract`` modules (and the suites' package, which is light) and no suite, not the
    suites' interface, no runner, no driver, no emulator and no numpy."""
    mods = _modules_after("from armbench.record.suite_contract import contracts; contracts()")
    assert {"armbench.bench.suites.accuracy_contract", "armbench.bench.suites.startup_contract",
            "armbench.bench.suites.twin_check_contract"} <= mods
    suites = {m for m in mods if m.startswith("armbench.bench.suites.")}
    assert all(m.endswith("_contract") for m in suites), suites  # not even the interface
    assert not any(m.startswith(("armbench.drivers.host.arm", "armbench.bench.runner",
                                 "armbench.fakes", "numpy")) for m in mods), sorted(mods)
