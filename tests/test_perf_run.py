"""``armbench perf --only run``: the phase clock of the timed default run."""

from __future__ import annotations

import asyncio
import importlib
import time
import types
from pathlib import Path

import pytest

from armbench.cli.perf import run_perf as perf_run


def test_a_phase_inside_another_is_charged_to_itself_only(
        monkeypatch: pytest.MonkeyPatch) -> None:
    now = [100.0]
    monkeypatch.setattr(time, "perf_counter", lambda: now[0])
    clock = perf_run._Clock()
    now[0] += 1.0                                     # other: 1 s

    def inner() -> None:
        now[0] += 2.0                                 # imports: 2 s

    timed_inner = clock.timed("imports", inner)

    def outer() -> None:
        now[0] += 3.0                                 # report: 3 s before the import
        timed_inner()
        now[0] += 4.0                                 # and 4 s after

    clock.timed("report", outer)()
    now[0] += 5.0                                     # other again: 5 s
    clock.leave()
    assert clock.seconds == {"other": 6.0, "report": 7.0, "imports": 2.0}
    assert set(clock.cpu_seconds) == set(clock.seconds)


def test_a_coroutine_is_timed_from_its_start_to_its_end() -> None:
    clock = perf_run._Clock()

    async def summarize() -> int:
        time.sleep(0.05)
        return 7

    timed = clock.timed("summaries", summarize)
    assert asyncio.run(timed()) == 7
    assert clock.seconds["summaries"] >= 0.05


def test_parts_that_are_not_found_are_named(monkeypatch: pytest.MonkeyPatch) -> None:
    target = types.SimpleNamespace(write=lambda: 1)
    module = types.ModuleType("armbench_perf_test_target")
    module.Writer = target  # type: ignore[attr-defined]
    monkeypatch.setitem(__import__("sys").modules, module.__name__, module)
    monkeypatch.setattr(perf_run, "PHASES", (("record", module.__name__, "Writer.write"),
                                             ("record", module.__name__, "Writer.gone"),
                                             ("report", "armbench_no_such_module", "f")))
    clock = perf_run._Clock()
    missing = perf_run._patch(clock)
    assert missing == [f"{module.__name__}.Writer.gone", "armbench_no_such_module.f"]
    assert target.write() == 1
    assert "record" in clock.seconds


def test_every_timed_part_names_code_that_exists() -> None:
    """A renamed module or method would leave its phase silently untimed."""
    for _, module_name, path in perf_run.PHASES:
        owner = importlib.import_module(module_name)
        for part in path.split("."):
            owner = getattr(owner, part)
        assert callable(owner), (module_name, path)


def test_the_trials_cover_only_the_seconds_of_their_spans_within_the_run() -> None:
    spans = [(1.0, 3.0), (2.0, 4.0), (6.0, 7.0), (-5.0, 0.5), (9.5, 20.0)]
    # 0..10: 1-4 (3 s, the overlap counted once), 6-7 (1 s), 0-0.5 and 9.5-10 clipped
    assert perf_run.covered_s(spans, 0.0, 10.0) == pytest.approx(5.0)
    assert perf_run.covered_s([], 0.0, 10.0) == 0.0


def test_each_committed_job_is_kept_with_its_cost_and_robot_time(
        monkeypatch: pytest.MonkeyPatch) -> None:
    from armbench.bench.runner import parallel
    from armbench.record import Trial

    committed: list[int] = []
    monkeypatch.setattr(parallel.ParallelTrials, "_commit",
                        lambda self, ps, index, attempt, result, wall_s: committed.append(index))
    jobs = perf_run._trial_jobs()
    result = parallel.JobResult(Trial(4, 0.0, 12.5), (), (), worker_s=0.5, worker_cpu_s=0.25,
                                worker_start_s=7.0)
    parallel.ParallelTrials._commit(None, None, 4, 0, result, 0.1)  # type: ignore[arg-type]
    assert committed == [4]
    assert jobs == [{"worker_s": 0.5, "cpu_s": 0.25, "start_s": 7.0, "robot_s": 12.5}]


def test_a_job_reports_its_cpu_and_when_it_began_in_its_worker(tmp_path: Path) -> None:
    """A trial job run as a worker runs it: its CPU seconds and its start on the machine's
    ``perf_counter`` come back with it (what ``run.serial_s`` and
    ``run.trials_per_bare_emulator`` are computed from)."""
    import dataclasses

    from armbench.bench.runner.arms import lay_out
    from armbench.bench.runner.options import RunOptions
    from armbench.bench.runner.parallel import TrialJob
    from armbench.bench.runner.plan import prepare
    from armbench.bench.workers.worker_process import run_job

    options = RunOptions(suites=["accuracy"], out=tmp_path / "run")
    plan = prepare(options, lay_out(options).arms[0])
    (ps,) = plan.suites
    plan.out_dir.mkdir(parents=True)
    job = TrialJob(dataclasses.replace(plan, suites=[]), dataclasses.replace(ps, trials=[]), 0, 0,
                   ps.trials[0])
    before = time.perf_counter()
    result = run_job(job)
    after = time.perf_counter()
    assert result.trial.status == "done" and result.trial.duration_s > 1.0
    assert before <= result.worker_start_s <= result.worker_start_s + result.worker_s <= after
    assert result.worker_cpu_s > 0.0


def test_the_cpu_spent_with_no_trial_running_is_what_falls_between_the_spans() -> None:
    trace = perf_run._CpuTrace(period_s=3600.0)
    trace.stop()
    # (wall, cpu) every second, 0.5 s of CPU each second but 0.1 s within 2..5
    trace.samples.clear()
    cpu = 0.0
    for t in range(10):
        trace.samples.append((float(t), cpu))
        cpu += 0.1 if 2 <= t < 5 else 0.5
    # the trials ran 1.5..5.5 and 5.2..6.8 (overlapping): the seconds from 1 to 7 are theirs
    # (their middles covered), 0-1, 7-8 and 8-9 (0.5 s of CPU each) are not
    assert perf_run._CpuTrace.cpu_outside(trace, [(5.2, 6.8), (1.5, 5.5)]) == pytest.approx(1.5)
    assert perf_run._CpuTrace.cpu_outside(trace, []) == pytest.approx(0.5 * 6 + 0.1 * 3)


def test_the_bare_emulator_yardstick_starts_when_told_and_reports_its_seconds(
        capsys: pytest.CaptureFixture[str]) -> None:
    """Each of the yardstick's two processes waits for the moment both were told (so the two
    run at once, as the workers do), then prints the wall and CPU seconds of its simulated
    seconds as one JSON line."""
    import json

    start_at = time.perf_counter() + 0.3
    perf_run.bare_child(5.0, start_at)
    assert time.perf_counter() >= start_at
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(figures) == {"wall_s", "cpu_s"}
    assert 0.0 < figures["cpu_s"] <= figures["wall_s"] + 0.05, figures
    assert figures["wall_s"] < 5.0, figures  # virtual time: far faster than the robot's
