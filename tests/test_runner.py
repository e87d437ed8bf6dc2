"""The bench runner (``armbench run``) end to end over ``fake://`` on virtual time.

Most tests use :class:`TinySuite` (a few short moves of joint 1, judged by the emulator's ground
truth) so they do not depend on the speed of the real suites; ``test_real_suite`` runs each real
suite once with minimal parameters when its module exists.
"""

from __future__ import annotations

import asyncio
import importlib
import io
import itertools
import json
import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import pytest

import armbench.bench.suites
import armbench.cli.main
from armbench.bench.runner import (
    EXIT_FAIL,
    EXIT_INCOMPLETE,
    EXIT_INTERRUPTED,
    EXIT_PASS,
    EXIT_REGRESSION,
    ProgressPrinter,
    RunOptions,
    RunOutcome,
    derive_seed,
    run_bench,
    run_sync,
)
from armbench.bench.runner.power import (
    CommandPower,
    EmulatorPower,
    HarnessPower,
    ManualPower,
    PowerError,
    port_power,
)
from armbench.bench.runner.truth import EmulatorTruth, TrackerError, load_tracker
from armbench.bench.suites import (
    SUITES,
    ReReferencing,
    Suite,
    SuiteContext,
    UnknownSuiteError,
    load_suite,
)
from armbench.cli.commands.run_files import write_reports
from armbench.drivers.capture.read import open_capture
from armbench.drivers.model.errors import ArmbenchError, PortLostError
from armbench.drivers.model.kinematics import tcp_position
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.record import Measurement, Trial, load_record

# --------------------------------------------------------------------------------------------
# A tiny suite: move joint 1 to a planned angle (plus a seeded random offset), measure


class TinySuite(Suite):
    """``tiny``: trial k moves joint 1 to ``(-1)^k (0.1 + 0.05 k)`` rad + U(-0.01, 0.01)."""

    name = "tiny"
    version = "1"
    fail_once: ClassVar[set[int]] = set()
    """Trial indices whose first attempt raises PortLostError (class-wide, for retry tests)."""
    interrupt_at: ClassVar[int | None] = None
    """Trial index that raises KeyboardInterrupt (Ctrl-C) when reached."""

    def default_params(self, settings: RobotSettings) -> dict[str, Any]:
        return {"trials": 3, "duty": 90}

    def validate(self, settings: RobotSettings, params: Mapping[str, Any]) -> None:
        from armbench.drivers.model.settings import SettingsError

        if not isinstance(params["trials"], int) or params["trials"] < 1:
            raise SettingsError("suites.tiny.trials", params["trials"], "must be >= 1")

    def metric_names(self, params: Mapping[str, Any]) -> frozenset[str]:
        return frozenset({"tiny.move_s", "tiny.error_mm", "tiny.move_mean_s",
                          "tiny.error_max_mm"})

    def plan(self, params: Mapping[str, Any]) -> list[dict[str, Any]]:
        return [{"q1": (-1) ** k * (0.1 + 0.05 * k)} for k in range(params["trials"])]

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        if index in TinySuite.fail_once:
            TinySuite.fail_once.discard(index)
            raise PortLostError(ctx.arm.port, "cable pulled (test)")
        if index == TinySuite.interrupt_at:
            raise KeyboardInterrupt
        loop = asyncio.get_running_loop()
        target = [trial_params["q1"] + ctx.rng.uniform(-0.01, 0.01), 0.0, 0.0, 0.0]
        t0 = loop.time()
        state = await ctx.arm.move_joints(target, int(ctx.params["duty"]))
        assert state is not None
        await asyncio.sleep(0.05)
        move_s = loop.time() - t0
        reported = state.tcp_m(ctx.settings)
        sample: dict[str, Any] = {"t_s": move_s, "reported_m": list(reported),
                                  "q_rad": list(state.q_rad)}
        ms = [ctx.judge("tiny.move_s", move_s, "s")]
        true_m = None if ctx.truth is None else ctx.truth.true_position_m()
        if true_m is not None:  # a truth source: the emulator on fake://, none on hardware
            sample["true_m"] = list(true_m)
            ms.append(ctx.judge("tiny.error_mm", 1000.0 * math.dist(reported, true_m), "mm"))
        return Trial(index, 0.0, 0.0, params=dict(trial_params), samples=[sample],
                     measurements=ms)

    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        moves = [m.value for t in trials for m in t.measurements if m.name == "tiny.move_s"]
        errs = [m.value for t in trials for m in t.measurements if m.name == "tiny.error_mm"]
        out = [ctx.judge("tiny.move_mean_s", sum(moves) / len(moves), "s")]
        if errs:
            out.append(ctx.judge("tiny.error_max_mm", max(errs), "mm"))
        return out


class DyingWorkerSuite(TinySuite):
    """``dying``: trial 1 ends the process measuring it (a worker killed by the OOM killer, say)
    when ``ARMBENCH_TEST_DIE`` is set in its environment; never in the test process itself."""

    name = "dying"

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        if index == 1 and os.environ.get("ARMBENCH_TEST_DIE") == str(os.getppid()):
            os._exit(3)
        return await super().run_trial(ctx, index, trial_params)


class BrokenSuite(TinySuite):
    """``broken``: trial 1 loses the port (a driver error), every time."""

    name = "broken"

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        if index == 1:
            raise PortLostError(ctx.arm.port, "cable pulled (test)")
        return await super().run_trial(ctx, index, trial_params)


@pytest.fixture(autouse=True)
def _tiny_registered(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setitem(SUITES, "tiny", f"{__name__}:TinySuite")
    monkeypatch.setitem(SUITES, "broken", f"{__name__}:BrokenSuite")
    monkeypatch.setitem(SUITES, "dying", f"{__name__}:DyingWorkerSuite")
    TinySuite.fail_once = set()
    TinySuite.interrupt_at = None
    yield


CONFIG = """\
spec_version = "armbench-limits/1"

[limits."tiny.move_s"]
high = {move_high}
unit = "s"

[limits."tiny.error_mm"]
high = 1.0
unit = "mm"

[regression]
default_tolerance_pct = 10.0

[regression.metrics."tiny.*"]
tolerance_pct = 10.0
tolerance_abs = 0.01

[suites.tiny]
trials = {trials}
"""


def write_config(tmp_path: Path, *, trials: int = 3, move_high: float = 60.0,
                 extra: str = "", name: str = "bench.toml") -> Path:
    path = tmp_path / name
    path.write_text(CONFIG.format(trials=trials, move_high=move_high) + extra)
    return path


class Emulators(list[Any]):
    """An emulator factory that keeps every emulator it builds."""

    def __call__(self, robot: Any, settings: Any, faults: Any) -> Any:
        from armbench.fakes.firmware.arm_emulator import ArmEmulator

        emulator = ArmEmulator(robot, settings, faults)
        self.append(emulator)
        return emulator


def run(options: RunOptions, emulators: Emulators | None = None,
        progress: io.StringIO | None = None) -> RunOutcome:
    """Run as ``armbench run`` does: the runner writes the record, then its reports."""
    outcome = run_virtual(run_bench(options, progress=progress, emulator_factory=emulators))
    write_reports(outcome.record, outcome.out_dir)
    return outcome


def measurements(record: Any) -> dict[str, tuple[float, str]]:
    """Every current measurement's value and outcome, keyed by suite/trial/name."""
    out: dict[str, tuple[float, str]] = {}
    for suite, trial, m in record.iter_measurements():
        where = f"{suite.name}/{'suite' if trial is None else trial.index}/{m.name}"
        out[where] = (m.value, m.outcome)
    return out


def assert_same_measurements(a: Any, b: Any) -> None:
    """Same names, outcomes and values; values equal to 1e-9 relative: a duration measured on the
    loop's clock is a difference of two absolute virtual times, and the same interval starting at
    another absolute time rounds differently in the last bits (positions are bit-identical)."""
    ma, mb = measurements(a), measurements(b)
    assert ma.keys() == mb.keys()
    for key in ma:
        assert ma[key][1] == mb[key][1], key
        assert ma[key][0] == pytest.approx(mb[key][0], rel=1e-9, abs=1e-12), key


# --------------------------------------------------------------------------------------------
# Registry


def test_registry_names_and_unknown_suite() -> None:
    assert list(SUITES)[:3] == ["accuracy", "repeatability", "startup-recovery"]
    with pytest.raises(UnknownSuiteError, match="known: accuracy, repeatability, "
                                                 "startup-recovery"):
        load_suite("nope")
    assert load_suite("tiny").name == "tiny"
    assert load_suite(f"{__name__}:TinySuite").name == "tiny"
    with pytest.raises(ArmbenchError, match="not a Suite"):
        load_suite(f"{__name__}:Emulators")
    with pytest.raises(ArmbenchError, match="cannot be imported"):
        load_suite("no.such.module:Suite")


# --------------------------------------------------------------------------------------------
# End to end


def test_run_end_to_end_writes_every_file(tmp_path: Path) -> None:
    out = tmp_path / "run"
    emulators = Emulators()
    progress = io.StringIO()
    outcome = run(RunOptions(suites=["tiny"], config=write_config(tmp_path), out=out, seed=7),
                  emulators, progress)
    assert outcome.exit_status == EXIT_PASS, progress.getvalue()
    record = load_record(out / "results.json")
    assert record.verdict == "pass"
    suite = record.suites["tiny"]
    assert [t.index for t in suite.trials] == [0, 1, 2]
    assert all(t.status == "done" for t in suite.trials)
    assert {m.name for m in suite.measurements} == {"tiny.move_mean_s", "tiny.error_max_mm"}
    # Trials are stamped on the run clock (virtual seconds), in order and without overlap.
    for a, b in zip(suite.trials, suite.trials[1:], strict=False):
        assert a.duration_s > 0.05 and b.started_s >= a.ended_s
    env = record.environment
    assert env.port == "fake://" and env.seed == 7 and env.faults == ()
    assert env.config_path is not None and env.config_path.endswith("bench.toml")
    # One fresh emulator per trial, each seeded from (seed, suite, index).
    assert len(emulators) == 3
    assert emulators[0].settings.seed == derive_seed(7, "emulator", "tiny", 0, 0)
    assert all(e.stats().commands >= 1 for e in emulators)
    # JUnit parses and has the measurements; the report exists; the capture is one stream on
    # the run clock.
    root = ET.parse(out / "junit.xml").getroot()
    names = {tc.get("name") for tc in root.iter("testcase")}
    assert {"tiny.move_s", "tiny.error_mm"} <= names  # judged: testcases
    props = {p.get("name") for p in root.iter("property")}
    assert {"tiny.move_mean_s", "tiny.error_max_mm"} <= props - names  # unjudged: properties
    assert (out / "report.html").read_text().lstrip().lower().startswith("<!doctype html")
    records = list(open_capture(out / "capture.mcap"))
    assert {r.dir for r in records} == {"in", "out"}
    times = [r.t_s for r in records]
    assert times == sorted(times) and times[-1] <= suite.ended_s  # type: ignore[operator]
    assert not list(out.glob(".capture.part*"))
    # Progress: one line per trial with k of n and a remaining-time estimate.
    lines = [line for line in progress.getvalue().splitlines() if "trial " in line]
    assert [line.split()[2] for line in lines] == ["1/3", "2/3", "3/3"]
    assert "remaining ~" in lines[-1] and "robot time" in lines[-1]


def test_limit_failure_exits_1(tmp_path: Path) -> None:
    """Measured in turn (``workers=1``): a limit is judged alike in a worker process
    (``test_parallel_trials_commit_in_order_on_one_run_clock``), which would cost a pool."""
    out = tmp_path / "run"
    outcome = run(RunOptions(suites=["tiny"], config=write_config(tmp_path, move_high=0.01),
                             out=out, workers=1))
    assert outcome.exit_status == EXIT_FAIL
    assert outcome.record.verdict == "fail"
    failures = ET.parse(out / "junit.xml").getroot().iter("failure")
    assert any("tiny.move_s" in (f.get("message") or "") for f in failures)


def test_trial_error_ends_the_suite_and_the_run_goes_on(tmp_path: Path) -> None:
    out = tmp_path / "run"
    outcome = run(RunOptions(suites=["broken", "tiny"], config=write_config(tmp_path), out=out))
    assert outcome.exit_status == EXIT_INCOMPLETE
    record = load_record(out / "results.json")
    broken = record.suites["broken"]
    assert broken.status == "error" and broken.error is not None
    assert "PortLostError" in broken.error and "trial 1" in broken.error
    assert [t.status for t in broken.trials] == ["done", "error"]  # trial 2 never ran
    assert record.suites["tiny"].status == "done"
    assert record.verdict == "error"


def test_retries_measure_an_errored_trial_again(tmp_path: Path) -> None:
    TinySuite.fail_once = {1}
    out = tmp_path / "run"
    progress = io.StringIO()
    outcome = run(RunOptions(suites=["tiny"], config=write_config(tmp_path), out=out, retries=1,
                             workers=1), progress=progress)  # fail_once lives in this process
    assert outcome.exit_status == EXIT_PASS
    suite = load_record(out / "results.json").suites["tiny"]
    assert [t.status for t in suite.trials] == ["done"] * 3
    assert [(t.index, t.status) for t in suite.superseded_trials] == [(1, "error")]
    # the retried trial is counted once: "run 3/3" at the end, never "run 4/3"
    counts = [line.split("run ")[1].split()[0] for line in progress.getvalue().splitlines()
              if " trial " in line and "run " in line]
    assert counts == ["1/3", "1/3", "2/3", "3/3"], counts


def test_one_emulator_for_the_whole_run_with_isolation_run(tmp_path: Path) -> None:
    config = write_config(tmp_path, extra='\n[bench]\nisolation = "run"\nsettle_s = 0.1\n')
    emulators = Emulators()
    outcome = run(RunOptions(suites=["tiny"], config=config, out=tmp_path / "r"), emulators)
    assert outcome.exit_status == EXIT_PASS
    assert len(emulators) == 1 and emulators[0].stats().commands >= 3
    trials = outcome.record.suites["tiny"].trials
    assert trials[1].started_s - trials[0].ended_s >= 0.1  # settle_s between trials


async def test_hardware_path_in_real_time_over_tcp(tmp_path: Path) -> None:
    """A port that is not fake:// runs in real time with one reconnecting connection, after the
    probe's connection found the arm there: here the emulator served on a TCP socket, as
    ``armbench emulate --tcp`` does for a remote robot."""
    from armbench.fakes.firmware.arm_emulator import ArmEmulator
    from armbench.fakes.links.serve import TcpServer

    server = TcpServer(ArmEmulator())
    host, port = await server.start()
    try:
        # the emulator shares this process's loop over a real socket: a starved process may
        # answer later than the default 0.5 s reply timeout, which a test cannot rely on
        config = write_config(tmp_path, trials=1,
                              extra="duty = 99\n\n[bench]\nreply_timeout_s = 5.0\n"
                              "connect_timeout_s = 30.0\nmove_timeout_scale = 10.0\n")
        outcome = await run_bench(RunOptions(suites=["tiny"], ports=[f"socket://{host}:{port}"],
                                             config=config, out=tmp_path / "r"))
    finally:
        await server.close()
    assert outcome.exit_status == EXIT_PASS, outcome.record.suites["tiny"].error
    record = load_record(tmp_path / "r" / "results.json")
    trial = record.suites["tiny"].trials[0]
    assert {m.name for m in trial.measurements} == {"tiny.move_s"}  # no truth on hardware
    assert trial.duration_s > 0.05  # real seconds on the loop's (monotonic) clock
    assert record.environment.port == f"socket://{host}:{port}"
    assert server.clients_served == 2  # the probe's connection, then the run's one
    assert list(open_capture(tmp_path / "r" / "capture.mcap"))


# --------------------------------------------------------------------------------------------
# Validation before motion


def _bad_options(tmp_path: Path) -> dict[str, tuple[RunOptions, str]]:
    good = write_config(tmp_path)
    bad_spec = tmp_path / "bad_spec.toml"
    bad_spec.write_text('spec_version = "armbench-limits/9"\n')
    bad_param = write_config(tmp_path, extra="speed = 3\n", name="bad_param.toml")
    bad_bench = write_config(tmp_path, extra="\n[bench]\nretrys = 2\n", name="bad_bench.toml")
    other_schema = tmp_path / "other.json"
    other_schema.write_text(json.dumps({"schema": "armbench-run/99"}))
    bad_faults = tmp_path / "faults.toml"
    bad_faults.write_text('[[faults]]\nkind = "meteor"\nat_s = 1.0\n')
    earlier = run(RunOptions(suites=["tiny"], config=write_config(tmp_path, trials=1),
                             out=tmp_path / "earlier"))
    old_version = tmp_path / "old_version.json"
    doc = json.loads(earlier.results_path.read_text())
    doc["suites"]["tiny"]["version"] = "0"
    old_version.write_text(json.dumps(doc))
    out = tmp_path / "never"
    return {
        "unknown suite": (RunOptions(suites=["tiny", "nope"], config=good, out=out),
                          "unknown suite 'nope'"),
        "limits spec": (RunOptions(suites=["tiny"], config=bad_spec, out=out), "spec_version"),
        "missing config": (RunOptions(suites=["tiny"], config=tmp_path / "none.toml", out=out),
                           "does not exist"),
        "suite param": (RunOptions(suites=["tiny"], config=bad_param, out=out),
                        "suites.tiny.speed"),
        "bench param": (RunOptions(suites=["tiny"], config=bad_bench, out=out), "bench.retrys"),
        "baseline missing": (RunOptions(suites=["tiny"], config=good, out=out,
                                        baseline=tmp_path / "nothing.json"), "does not exist"),
        "baseline schema": (RunOptions(suites=["tiny"], config=good, out=out,
                                       baseline=other_schema), "armbench-run/99"),
        "baseline suite version": (RunOptions(suites=["tiny"], config=good, out=out,
                                              baseline=old_version), "suites.tiny.version"),
        "missing serial device": (RunOptions(suites=["tiny"], config=good, out=out,
                                             ports=[str(tmp_path / "ttyNOPE0")]),
                                  "no such serial device"),
        "port scheme": (RunOptions(suites=["tiny"], config=good, out=out, ports=["warp://x"]),
                        "unknown transport scheme"),
        "faults file": (RunOptions(suites=["tiny"], config=good, out=out, faults=bad_faults),
                        "faults[0].kind"),
        "faults on hardware": (RunOptions(suites=["tiny"], config=good, out=out,
                                          ports=["socket://127.0.0.1:9"], faults=bad_faults),
                               "--faults"),
        "tracker": (RunOptions(suites=["tiny"], config=good, out=out, tracker="nope:Tracker"),
                    "--tracker"),
        "power on fake": (RunOptions(suites=["tiny"], config=good, out=out, power_manual=True),
                          "--power"),
        "negative retries": (RunOptions(suites=["tiny"], config=good, out=out, retries=-1),
                             "--retries"),
    }


def test_validation_errors_stop_the_run_before_the_arm_moves(tmp_path: Path) -> None:
    for label, (options, expected) in _bad_options(tmp_path).items():
        emulators = Emulators()
        with pytest.raises(ArmbenchError) as info:
            run(options, emulators)
        assert expected in str(info.value), (label, str(info.value))
        assert "\n" not in str(info.value), label
        assert emulators == [], label  # no emulator was even built: nothing could move
        assert not (tmp_path / "never").exists(), label


def test_cli_validation_error_is_one_line_and_status_2(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    status = armbench.cli.main.main(["run", "tiny", "--config", str(write_config(tmp_path)),
                             "--out", str(tmp_path / "r"), "--port", "warp://x"])
    assert status == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown transport scheme warp://" in err[0]
    assert not (tmp_path / "r").exists()


# --------------------------------------------------------------------------------------------
# Interruption and resume


class _CancelAfter(io.StringIO):
    """A progress stream that cancels ``task`` once ``n`` trial lines were shown."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.n = n
        self.task: asyncio.Task[RunOutcome] | None = None

    def write(self, s: str) -> int:
        if " trial " in s and "done" in s:
            self.n -= 1
            if self.n == 0 and self.task is not None:
                self.task.cancel()
        return super().write(s)


def test_resume_after_cancellation_matches_an_uninterrupted_run(tmp_path: Path) -> None:
    config = write_config(tmp_path, trials=5)
    whole = run(RunOptions(suites=["tiny", "broken"], config=config, out=tmp_path / "a", seed=3))
    assert whole.record.verdict == "error"  # broken's trial 1 errs: still compares

    out = tmp_path / "b"
    stream = _CancelAfter(4)

    async def interrupted() -> None:
        task = asyncio.get_running_loop().create_task(run_bench(
            RunOptions(suites=["tiny", "broken"], config=config, out=out, seed=3),
            progress=stream))
        stream.task = task
        with pytest.raises(asyncio.CancelledError):
            await task

    run_virtual(interrupted())
    partial = load_record(out / "results.json")
    assert partial.verdict == "incomplete"
    assert [t.index for t in partial.suites["tiny"].trials] == [0, 1, 2, 3]
    assert partial.suites["tiny"].status == "running"
    assert "interrupted" in stream.getvalue() and "--resume" in stream.getvalue()
    write_reports(partial, out)  # as armbench run does with the record of an interrupted run
    assert (out / "junit.xml").exists() and (out / "report.html").exists()

    emulators = Emulators()
    resumed = run(RunOptions(resume=out), emulators)
    assert resumed.record.resumed and len(resumed.record.resumed) == 1
    # Trials 0..3 were not measured again: one emulator for tiny trial 4, two for broken.
    assert len(emulators) == 3
    assert_same_measurements(resumed.record, whole.record)
    errors = {k: v for k, v in measurements(whole.record).items() if "error_mm" in k}
    assert errors == {k: v for k, v in measurements(resumed.record).items() if "error_mm" in k}
    assert resumed.record.verdict == whole.record.verdict
    assert resumed.exit_status == whole.exit_status == EXIT_INCOMPLETE
    # The capture of both sessions is one stream on the continued run clock.
    times = [r.t_s for r in open_capture(out / "capture.mcap")]
    assert times == sorted(times)


class _CancelWhileConnecting(io.StringIO):
    """A progress stream that cancels ``task`` (what Ctrl-C does to ``asyncio.run``'s task)
    ``after_s`` of loop time after the line of trial 1 (the next trial is connecting then)."""

    def __init__(self, after_s: float) -> None:
        super().__init__()
        self.after_s = after_s
        self.task: asyncio.Task[RunOutcome] | None = None

    def write(self, s: str) -> int:
        if " trial 1/" in s and "done" in s and self.task is not None:
            asyncio.get_running_loop().call_later(self.after_s, self.task.cancel)
        return super().write(s)


def test_ctrl_c_while_a_trial_connects_keeps_its_frames_out_of_the_capture(
        tmp_path: Path) -> None:
    """Each trial's fresh arm garbles its replies for its first second: its connection waits for
    a valid reply while the garbage is captured. Ctrl-C half-way through trial 2's connection:
    the capture holds no frame of that trial (its record does not hold it), and the resumed run's
    capture is the uninterrupted one's. (Ctrl-C landing between an arm's first reply and the
    connection's return is the same case, in a window too short to hit by hand: a resumed
    ``test_run_folder_safety.py`` run under load had a frame too many.)"""
    config = write_config(tmp_path, trials=3)
    faults = tmp_path / "garbled-start.toml"
    faults.write_text('[[faults]]\nkind = "uart_corrupt"\nat_s = 0.0\nduration_s = 1.0\n'
                      'probability = 1.0\n')
    inputs: dict[str, Any] = {"suites": ["tiny"], "config": config, "seed": 3, "faults": faults,
                              "workers": 1}
    whole = run(RunOptions(out=tmp_path / "a", **inputs))
    assert whole.record.verdict == "pass"
    out = tmp_path / "b"
    stream = _CancelWhileConnecting(0.5)

    async def interrupted() -> None:
        task = asyncio.get_running_loop().create_task(run_bench(
            RunOptions(out=out, **inputs), progress=stream))
        stream.task = task
        with pytest.raises(asyncio.CancelledError):
            await task

    run_virtual(interrupted())
    partial = load_record(out / "results.json")
    (trial,) = partial.suites["tiny"].trials
    frames = list(open_capture(out / "capture.mcap"))
    assert any(r.error is not None for r in frames)  # trial 1's garbled start is captured
    assert [r for r in frames if r.t_s > trial.ended_s + 1e-6] == []
    assert len(list(out.glob(".capture.part*"))) == 1  # trial 2's, for the resume to judge
    run(RunOptions(resume=out, workers=1))
    assert list(open_capture(out / "capture.mcap")) == list(open_capture(tmp_path / "a"
                                                                         / "capture.mcap"))
    assert not list(out.glob(".capture.part*"))


def test_resume_refuses_changed_inputs(tmp_path: Path) -> None:
    config = write_config(tmp_path, trials=2)
    out = tmp_path / "r"
    TinySuite.interrupt_at = 1
    with pytest.raises(KeyboardInterrupt):
        run(RunOptions(suites=["tiny"], config=config, out=out, workers=1))
    TinySuite.interrupt_at = None
    with pytest.raises(ArmbenchError, match="--seed"):
        run(RunOptions(resume=out, seed=5))
    config.write_text(CONFIG.format(trials=4, move_high=60.0))
    with pytest.raises(ArmbenchError, match=r"suites\.tiny\.params"):
        run(RunOptions(resume=out))


def test_ctrl_c_exits_130_and_resume_completes(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r"
    TinySuite.interrupt_at = 2
    args = ["run", "tiny", "--config", str(write_config(tmp_path)), "--out", str(out),
            "--workers", "1"]  # interrupt_at lives in this process
    assert armbench.cli.main.main(args) == EXIT_INTERRUPTED
    record = load_record(out / "results.json")
    assert [t.index for t in record.suites["tiny"].trials] == [0, 1]
    assert record.verdict == "incomplete"
    assert "--resume" in capsys.readouterr().out
    # the command renders the reports of the record the interrupted runner left
    assert (out / "junit.xml").exists() and (out / "report.html").exists()
    TinySuite.interrupt_at = None
    assert armbench.cli.main.main(["run", "--resume", str(out)]) == EXIT_PASS
    record = load_record(out / "results.json")
    assert [t.index for t in record.suites["tiny"].trials] == [0, 1, 2]
    assert record.verdict == "pass"


# --------------------------------------------------------------------------------------------
# Regression gate and CLI


def test_regression_gate_fails_on_an_injected_fault(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The clean runs are measured in turn (``--workers 1``, no pool of processes to start),
    the faulted one in worker processes as by default: a trial's figures are the same either
    way (``test_parallel_trials_commit_in_order_on_one_run_clock``), so only the fault can
    regress them."""
    config = str(write_config(tmp_path))
    clean = tmp_path / "clean"
    assert armbench.cli.main.main(["run", "tiny", "--config", config, "--workers", "1",
                                   "--out", str(clean)]) == EXIT_PASS
    same = tmp_path / "same"
    assert armbench.cli.main.main(["run", "tiny", "--config", config, "--workers", "1",
                                   "--out", str(same),
                                   "--baseline", str(clean / "results.json")]) == EXIT_PASS
    assert not load_record(same / "results.json").baseline.regressed  # type: ignore[union-attr]

    faults = tmp_path / "stall.toml"  # joint 1 blocked for 0.3 s in every trial
    faults.write_text('[[faults]]\nkind = "stall"\njoint = 1\nat_s = 0.02\nduration_s = 0.3\n')
    worse = tmp_path / "worse"
    capsys.readouterr()
    status = armbench.cli.main.main(["run", "tiny", "--config", config, "--out", str(worse),
                             "--faults", str(faults), "--baseline", str(clean / "results.json")])
    printed = capsys.readouterr().out
    assert status == EXIT_REGRESSION, printed
    record = load_record(worse / "results.json")
    assert record.verdict == "regression"
    assert record.environment.faults[0]["kind"] == "stall"
    assert "tiny.move_mean_s" in {r.name for r in record.baseline.regressions}  # type: ignore[union-attr]
    assert "REGRESSED  tiny.move_mean_s" in printed
    root = ET.parse(worse / "junit.xml").getroot()
    assert any(f.get("type") == "regression" for f in root.iter("failure"))


def test_default_config_is_valid_and_names_real_metrics() -> None:
    from armbench.bench.runner import DEFAULT_CONFIG
    from armbench.record.limits import load_limits
    from armbench.record.suite_contract import contracts

    config = load_limits(DEFAULT_CONFIG)
    assert config.limits, "the default limits file judges something"
    prefixes = {getattr(c, "prefix", c.suite) for c in contracts()}
    assert {"accuracy", "repeatability", "startup"} <= prefixes
    for limit in config.limits.values():
        assert limit.metric.split(".")[0] in prefixes, limit.metric  # a registered suite's
        assert limit.unit in {"mm", "mrad", "s", "%", ""}
    assert config.bench_params() == {}  # every runner default stays commented
    assert config.suites == {}


def test_default_config_shows_each_suites_current_defaults() -> None:
    """The commented ``[suites.<name>]`` tables must stay equal to ``default_params``."""
    import tomllib

    from armbench.bench.runner import DEFAULT_CONFIG

    tables: dict[str, list[str]] = {}
    current: list[str] | None = None
    for line in DEFAULT_CONFIG.read_text().splitlines():
        if line.startswith("# [suites."):
            current = tables.setdefault(line[len("# [suites."):].rstrip("]"), [])
        elif current is not None and line.startswith("# ") and " = " in line:
            current.append(line[2:])
        else:
            current = None
    for name in ("accuracy", "repeatability", "startup-recovery"):
        try:
            suite = load_suite(name)
        except ArmbenchError as exc:
            pytest.skip(f"suite {name} not loadable yet: {exc}")
        shown = tomllib.loads("\n".join(tables.get(suite.name, [])))
        assert shown == suite.default_params(RobotSettings()), name


# --------------------------------------------------------------------------------------------
# The real suites, once each with minimal parameters


MINIMAL: dict[str, str] = {
    "accuracy": "laps = 1\nstyles = [\"coordinated\"]\nside_m = 0.04\n",
    "repeatability": ("cycles = 2\nspeeds_pct = [100]\nvap_cycles = 0\npath_cycles = 1\n"
                      "settle_s = 0.05\n"),
    "startup-recovery": ("trials = 1\nconditions = [\"cw-away-near\"]\njoint_sets = [[2, 3, 4]]\n"
                         "wear_duration_s = 0.0\n"),
}


@pytest.mark.parametrize("name", list(MINIMAL))
def test_real_suite_runs_with_minimal_parameters(name: str, tmp_path: Path) -> None:
    """Measured in turn (``workers=1``): the real suites in worker processes are the default
    run's (``test_report_real.py``)."""
    module = SUITES[name].partition(":")[0]
    try:
        importlib.import_module(module)
    except ImportError as exc:
        pytest.skip(f"{module} is not there yet ({exc})")
    suite = load_suite(name)
    table = MINIMAL[name]
    config = tmp_path / "bench.toml"
    config.write_text(f'spec_version = "armbench-limits/1"\n\n[suites.{suite.name}]\n{table}')
    out = tmp_path / "run"
    outcome = run(RunOptions(suites=[name], config=config, out=out, workers=1))
    record = load_record(out / "results.json")
    rec = record.suites[suite.name]
    assert rec.status == "done", rec.error
    assert rec.trials and all(t.status == "done" for t in rec.trials), [
        t.error for t in rec.trials]
    assert rec.measurements
    assert outcome.exit_status in (EXIT_PASS, EXIT_FAIL)
    assert (out / "junit.xml").exists() and (out / "report.html").exists()


# --------------------------------------------------------------------------------------------
# Power switches, measurement sources, progress


class _FakeEmulator:
    def __init__(self) -> None:
        self.events: list[str] = []
        self.q = (0.3, 0.2, -0.4, 0.1)

    def power_off(self) -> None:
        self.events.append("off")

    def power_on(self) -> None:
        self.events.append("on")

    def true_angles_rad(self) -> tuple[float, ...]:
        return self.q


class _Holder:
    def __init__(self, emulator: Any) -> None:
        self.emulator = emulator


async def test_emulator_power_follows_the_arm_to_its_emulator() -> None:
    first, second = _FakeEmulator(), _FakeEmulator()
    holder = _Holder(first)
    power = EmulatorPower(holder)
    await power.power_off()
    holder.emulator = second  # a reconnection brought a new emulator
    await power.power_on()
    assert first.events == ["off"] and second.events == ["on"]
    await EmulatorPower(first).power_on()
    assert first.events == ["off", "on"]
    with pytest.raises(PowerError, match="no emulator"):
        await EmulatorPower(_Holder(None)).power_off()


class _FakeHarness:
    """Stands in for the firmware harness process (tests/test_firmware_loop.py runs the real
    one): the control lines it would receive."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    async def power(self, on: bool) -> None:
        self.lines.append("power on" if on else "power off")

    async def re_reference(self) -> None:
        self.lines.append("re-reference")


class _Transport:
    def __init__(self, harness: Any) -> None:
        self.harness = harness


class _ArmOn:
    def __init__(self, transport: Any) -> None:
        self.transport = transport


async def test_port_power_is_the_ports_own_switch() -> None:
    """fake:// gets the emulator's switch, avr:// the harness's (following the arm's current
    transport), hardware none; both own switches can re-reference, a relay cannot."""
    emulator = _FakeEmulator()
    assert isinstance(port_power(emulator), EmulatorPower)
    assert isinstance(port_power(_Holder(emulator)), EmulatorPower)
    assert port_power(_ArmOn(_Transport(None))) is None
    assert port_power(_Holder(None)) is None
    first, second = _FakeHarness(), _FakeHarness()
    arm = _ArmOn(_Transport(first))
    power = port_power(arm)
    assert isinstance(power, HarnessPower) and isinstance(power, ReReferencing)
    await power.power_off()
    await power.re_reference()
    arm.transport = _Transport(second)  # a reconnection started a new harness
    await power.power_on()
    assert first.lines == ["power off", "re-reference"] and second.lines == ["power on"]
    assert not isinstance(CommandPower("true", "true"), ReReferencing)
    assert not isinstance(ManualPower(), ReReferencing)
    arm.transport = _Transport(None)
    with pytest.raises(PowerError, match="no firmware harness"):
        await power.power_off()


async def test_command_power_runs_commands_and_reports_failures(tmp_path: Path) -> None:
    log = tmp_path / "relay.log"
    script = tmp_path / "relay.sh"
    script.write_text(f'#!/bin/sh\necho "$1" >> {log}\n[ "$1" != fail ] || '
                      '{ echo "relay stuck" >&2; exit 3; }\n')
    script.chmod(0o755)
    power = CommandPower(f"{script} off", [str(script), "on"])
    power.check()
    await power.power_off()
    await power.power_on()
    assert log.read_text().split() == ["off", "on"]
    with pytest.raises(PowerError, match="exited with status 3: relay stuck"):
        await CommandPower(f"{script} fail", f"{script} on").power_off()
    with pytest.raises(PowerError, match=r"did not finish within 0\.2 s"):
        await CommandPower("sleep 5", "true", timeout_s=0.2).power_off()
    with pytest.raises(PowerError, match="not found"):
        CommandPower("no-such-relay-tool off", "true").check()
    with pytest.raises(PowerError, match="empty"):
        CommandPower("", "true")


async def test_manual_power_waits_for_enter_on_a_pipe() -> None:
    r, w = os.pipe()
    with os.fdopen(r, "r") as reader, os.fdopen(w, "w") as writer:
        prompts = io.StringIO()
        power = ManualPower(reader, prompts)
        task = asyncio.get_running_loop().create_task(power.power_off())
        await asyncio.sleep(0.05)
        assert not task.done()  # waiting for the operator
        writer.write("\n")
        writer.flush()
        await asyncio.wait_for(task, 5)
        assert "power OFF" in prompts.getvalue()
        writer.close()
        with pytest.raises(PowerError, match="input closed"):
            await asyncio.wait_for(power.power_on(), 5)


def test_emulator_truth_is_forward_kinematics_of_the_true_joints() -> None:
    emulator = _FakeEmulator()
    settings = RobotSettings()
    truth = EmulatorTruth(_Holder(emulator), settings)
    assert truth.true_joints_rad() == emulator.q
    expected = tcp_position(emulator.q, settings)
    assert truth.true_position_m() == pytest.approx(tuple(expected), abs=1e-12)
    assert EmulatorTruth(_Holder(None), settings).true_position_m() is None


class Tracker:
    """A PoseSource plug-in for the tests: a fixed position."""

    def __init__(self, settings: RobotSettings, offset_m: float = 0.0) -> None:
        self.offset_m = offset_m

    def true_position_m(self) -> tuple[float, float, float]:
        return (0.4 + self.offset_m, 0.0, 0.5)

    def true_joints_rad(self) -> None:
        return None


def test_tracker_plugin_is_loaded_and_checked() -> None:
    tracker = load_tracker(f"{__name__}:Tracker", RobotSettings(), {"offset_m": 0.1})
    assert tracker.true_position_m() == pytest.approx((0.5, 0.0, 0.5))
    with pytest.raises(TrackerError, match="module:Class"):
        load_tracker("justaname", RobotSettings())
    with pytest.raises(TrackerError, match="true_position_m"):
        load_tracker(f"{__name__}:_Holder", RobotSettings(), {"emulator": None})


class OpenedTracker(Tracker):
    """A tracker plug-in with the optional async open/close the runner awaits."""

    events: ClassVar[list[str]] = []

    async def open(self) -> None:
        OpenedTracker.events.append("open")

    async def close(self) -> None:
        OpenedTracker.events.append("close")


def test_tracker_replaces_the_emulator_truth_in_a_run(tmp_path: Path) -> None:
    OpenedTracker.events = []
    out = tmp_path / "r"
    outcome = run(RunOptions(suites=["tiny"], config=write_config(tmp_path, trials=1), out=out,
                             tracker=f"{__name__}:OpenedTracker"))
    assert OpenedTracker.events == ["open", "close"]
    trial = load_record(out / "results.json").suites["tiny"].trials[0]
    assert trial.samples[0]["true_m"] == [0.4, 0.0, 0.5]  # the tracker's, not the emulator's
    assert outcome.exit_status == EXIT_FAIL  # far from the reported TCP: tiny.error_mm fails


def test_progress_printer_rewrites_its_line_on_a_terminal() -> None:
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    stream = Tty()
    printer = ProgressPrinter(stream, 4)
    printer.plan("a", 2)
    printer.plan("b", 2)
    printer.trial("a", 1, 2, "done", 2.0)
    printer.trial("a", 2, 2, "done", 4.0)
    assert printer.estimate_s() == pytest.approx(6.0)  # b has no trial yet: the run's mean
    printer.message("[a] done")
    printer.finish()
    text = stream.getvalue()
    assert text.count("\r\x1b[K") == 2 and "[a] trial 2/2 done" in text
    assert text.endswith("[a] done\n")


# --------------------------------------------------------------------------------------------


def test_run_sync_picks_the_virtual_loop_for_fake(tmp_path: Path) -> None:
    from armbench.fakes.clock.vclock import VirtualTimeLoop

    seen: list[type] = []

    class Probe(Emulators):
        def __call__(self, robot: Any, settings: Any, faults: Any) -> Any:
            seen.append(type(asyncio.get_running_loop()))
            return super().__call__(robot, settings, faults)

    outcome = run_sync(RunOptions(suites=["tiny"], config=write_config(tmp_path, trials=1),
                                  out=tmp_path / "r"), progress=None, emulator_factory=Probe())
    assert outcome.exit_status == EXIT_PASS
    assert seen == [VirtualTimeLoop]


def test_parallel_trials_commit_in_order_on_one_run_clock(tmp_path: Path) -> None:
    """``fake://`` trials measured by two worker processes
    (``armbench.bench.workers.worker_process``): committed in index order, each starting where the
    previous ended on the run clock, the capture one stream on that clock holding every trial's
    frames; the same figures and trial times as the same trials measured in turn on one loop."""
    config = write_config(tmp_path, trials=4)
    runs = {}
    for workers in (2, 1):
        out = tmp_path / f"w{workers}"
        outcome = run(RunOptions(suites=["tiny"], config=config, out=out, workers=workers,
                                 seed=3))
        assert outcome.exit_status == EXIT_PASS
        runs[workers] = load_record(out / "results.json")
    trials = runs[2].suites["tiny"].trials
    assert [t.index for t in trials] == [0, 1, 2, 3]
    for a, b in itertools.pairwise(trials):
        assert b.started_s == pytest.approx(a.started_s + a.duration_s, abs=1e-9)
    capture = list(open_capture(tmp_path / "w2" / "capture.mcap"))
    times = [r.t_s for r in capture]
    assert times == sorted(times)
    assert times[0] >= trials[0].started_s and times[-1] <= trials[-1].ended_s + 1e-6
    for t in trials:  # frames of every trial, inside its span
        assert sum(t.started_s <= x <= t.ended_s + 1e-6 for x in times) > 50
    assert not list((tmp_path / "w2").glob(".capture.part*"))
    assert measurements(runs[2]).keys() == measurements(runs[1]).keys()
    for key, (value, outcome_) in measurements(runs[2]).items():
        assert outcome_ == measurements(runs[1])[key][1], key
        assert value == pytest.approx(measurements(runs[1])[key][0], rel=1e-9, abs=1e-12), key
    assert [x for t in trials for x in (t.started_s, t.duration_s)] == pytest.approx(
        [x for t in runs[1].suites["tiny"].trials for x in (t.started_s, t.duration_s)], abs=1e-9)
    # each trial's wall-clock time, measured in the worker, crossed back with it; junit.xml
    # gives it, never the robot time
    suite = runs[2].suites["tiny"]
    assert suite.wall_s is not None and all(t.wall_s is not None and 0 < t.wall_s < suite.wall_s
                                            for t in trials)
    head = ET.parse(tmp_path / "w2" / "junit.xml").getroot().find("testsuite[@name='tiny']")
    assert head is not None and head.get("time") == f"{suite.wall_s:.3f}"
    for t in trials:
        first = head.find(f"testcase[@classname='armbench.tiny.trial{t.index}']")
        assert first is not None and first.get("time") == f"{t.wall_s:.3f}"


def test_a_worker_that_dies_is_a_trial_error_and_the_run_goes_on(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A worker process killed mid-trial: that trial is in error (the suite stops, as for any
    trial error), the trials before it stay in the record, and the next suite runs on new
    workers."""
    monkeypatch.setenv("ARMBENCH_TEST_DIE", str(os.getpid()))
    out = tmp_path / "run"
    outcome = run(RunOptions(suites=["dying", "tiny"], config=write_config(tmp_path), out=out,
                             workers=2))
    assert outcome.exit_status == EXIT_INCOMPLETE
    record = load_record(out / "results.json")
    dying = record.suites["dying"]
    assert dying.status == "error" and dying.error is not None and "worker" in dying.error
    assert [(t.index, t.status) for t in dying.trials] == [(0, "done"), (1, "error")]
    assert record.suites["tiny"].status == "done"
    assert [t.status for t in record.suites["tiny"].trials] == ["done"] * 3
