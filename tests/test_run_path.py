"""One run path: ``armbench run`` hands one options object to the runner, which lays the arms out
(one, or a fleet), prepares, probes and runs each through the same code; a run of one arm is a
fleet of one, laid out as a run folder of its own. Real runs of a tiny suite on ``fake://`` (the
emulator in-process, on virtual time); the command line's outputs of both layouts are pinned in
``tests/test_fleet.py``, ``tests/test_runner.py`` and ``tests/test_exit_classes.py``."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from test_runner import write_config

from armbench.bench.runner import (
    RunOptions,
    RunOutcome,
    lay_out,
    prepare,
    run_arms_sync,
    run_sync,
)
from armbench.bench.runner.lock import LOCK_FILE
from armbench.bench.suites import SUITES
from armbench.drivers.model.errors import ArmbenchError
from armbench.record import RESULTS_FILE, load_record
from armbench.record.fleet_index import FLEET_FILE, read_fleet_index


@pytest.fixture(autouse=True)
def _tiny_registered(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setitem(SUITES, "tiny", "test_runner:TinySuite")
    yield


def _locked_reports(folder: Path, seen: list[Path]) -> Callable[[RunOutcome], None]:
    """A ``then`` that checks the run's folder is still locked when each arm's outcome comes."""
    def then(outcome: RunOutcome) -> None:
        assert (folder / LOCK_FILE).exists(), "the run's folder is locked while reports are made"
        seen.append(outcome.out_dir)
    return then


def test_one_arm_and_a_fleet_take_the_same_path(tmp_path: Path) -> None:
    config = write_config(tmp_path, trials=2)
    single, fleet = tmp_path / "single", tmp_path / "fleet"
    seen: list[Path] = []
    one = run_arms_sync(RunOptions(suites=["tiny"], ports=["solo=fake://?seed=5"],
                                   config=config, out=single, workers=1), progress=None,
                        then=_locked_reports(single, seen))
    many = run_arms_sync(RunOptions(suites=["tiny"], ports=["a=fake://", "b=fake://?seed=5"],
                                    config=config, out=fleet, workers=1), progress=None,
                         then=_locked_reports(fleet, seen))
    assert seen == [single, fleet / "a", fleet / "b"]
    # a fleet of one is laid out as a run folder of its own, no fleet index
    assert not one.fleet and one.out_dir == single and one.only().out_dir == single
    assert (single / RESULTS_FILE).is_file() and not (single / FLEET_FILE).exists()
    assert many.fleet and many.exit_status == 0 and many.failed == []
    assert [x.name for x in read_fleet_index(fleet).arms] == ["a", "b"]
    # the same arm measures the same, alone or in a fleet: one path
    alone, in_fleet = load_record(single / RESULTS_FILE), load_record(fleet / "b" / RESULTS_FILE)
    assert alone.environment.port == in_fleet.environment.port == "fake://?seed=5"
    assert ([t.measurements for t in alone.suites["tiny"].trials]
            == [t.measurements for t in in_fleet.suites["tiny"].trials])
    assert run_sync(RunOptions(resume=single), progress=None).exit_status == 0  # nothing left
    with pytest.raises(ArmbenchError, match="2 arms"):
        many.only()


def test_each_arm_is_prepared_from_its_own_layout(tmp_path: Path) -> None:
    config = write_config(tmp_path, trials=1)
    options = RunOptions(suites=["tiny"], ports=["a=fake://", "fake://?seed=3"], config=config,
                         out=tmp_path / "fleet", baseline=None)
    layout = lay_out(options)
    assert layout.fleet and layout.out_dir == tmp_path / "fleet"
    plans = [prepare(options, arm) for arm in layout.arms]
    assert [(p.port, p.out_dir.name, p.dut.name, p.run_id) for p in plans] == [
        ("fake://", "a", "a", f"{layout.fleet_id}-a"),
        ("fake://?seed=3", "fake-seed-3", "fake-seed-3", f"{layout.fleet_id}-fake-seed-3")]
    with pytest.raises(ArmbenchError, match="2 arms"):
        prepare(options)  # which arm? each is prepared on its own
    single = lay_out(RunOptions(ports=["x=fake://"], runs_root=tmp_path / "runs", dut="unit-7"))
    (arm,) = single.arms
    assert not single.fleet and arm.name is None and arm.dut == "unit-7"
    assert arm.run_id is not None and arm.out == tmp_path / "runs" / arm.run_id


def test_folders_of_the_other_layout_are_refused(tmp_path: Path) -> None:
    """A run of one arm into a fleet's folder, or a resume of one arm on several ports, is
    refused before anything is made."""
    config = write_config(tmp_path, trials=1)
    fleet = tmp_path / "fleet"
    run_arms_sync(RunOptions(suites=["tiny"], ports=["a=fake://", "b=fake://?seed=2"],
                             config=config, out=fleet, workers=1), progress=None)
    before = sorted(p.name for p in fleet.iterdir())
    with pytest.raises(ArmbenchError, match="already holds a fleet run"):
        run_arms_sync(RunOptions(suites=["tiny"], config=config, out=fleet), progress=None)
    assert sorted(p.name for p in fleet.iterdir()) == before
    one = tmp_path / "one"
    run_sync(RunOptions(suites=["tiny"], config=config, out=one, workers=1), progress=None)
    with pytest.raises(ArmbenchError, match="the run of one arm"):
        run_arms_sync(RunOptions(resume=one, ports=["fake://", "fake://?seed=2"]), progress=None)
    with pytest.raises(ArmbenchError, match="continues on the ports it began with"):
        run_arms_sync(RunOptions(resume=fleet, ports=["fake://"]), progress=None)


def test_the_runner_imports_nothing_of_the_command_line() -> None:
    """Options flow one way: the command line builds them, the runner reads them."""
    code = ("import sys, armbench.bench.runner, armbench.bench.runner.fleet_run; "
            "print('\\n'.join(sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True)
    assert [m for m in done.stdout.split() if m.startswith("armbench.cli")] == []
