"""What a run's caller does while the trials go on (``run_arms_sync(meanwhile=...)``: the run
command imports the report's modules then, not after the last trial)."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from armbench.bench.runner import RunOptions, run_arms_sync
from armbench.record import load_record


@pytest.mark.parametrize("ports", [[], ["a=fake://", "b=fake://?seed=3"]])
def test_meanwhile_runs_once_in_a_thread_of_its_own_once_a_trial_is_recorded(
        tmp_path: Path, ports: list[str]) -> None:
    out = tmp_path / "run"
    records = [out / "results.json"] if not ports else [out / "a" / "results.json",
                                                       out / "b" / "results.json"]
    seen: list[tuple[str, int]] = []
    done = threading.Event()

    def meanwhile() -> None:
        trials = sum(len(s.trials) for r in records if r.exists()
                     for s in load_record(r).suites.values())
        seen.append((threading.current_thread().name, trials))
        done.set()

    result = run_arms_sync(RunOptions(suites=["accuracy"], ports=ports, workers=1, out=out),
                           progress=None, meanwhile=meanwhile)
    assert result.exit_status == 0
    assert done.wait(60)
    ((thread, trials),) = seen
    assert thread != threading.main_thread().name and trials >= 1


def test_the_run_command_loads_the_report_while_the_trials_go_on(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from armbench.cli.commands import run, run_files
    from armbench.cli.main import main

    threads: list[str] = []
    preload = run_files.preload_reports

    def watched() -> None:
        threads.append(threading.current_thread().name)
        preload()

    monkeypatch.setattr(run, "preload_reports", watched)
    status = main(["run", "accuracy", "--workers", "1", "--out", str(tmp_path / "run")])
    assert status == 0 and (tmp_path / "run" / "report.html").exists()
    assert len(threads) == 1 and threads[0] != threading.main_thread().name
