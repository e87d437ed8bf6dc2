"""Progress you can read: ``armbench run`` shows one line per suite (rewritten in place on a
terminal, written when a suite begins, every ``LOG_INTERVAL_S`` and when it ends in a CI log),
a line per trial with ``-v`` and the verdict alone with ``-q``. The command runs in a real
pseudo-terminal for the terminal case and with pipes for the CI case."""

from __future__ import annotations

import io
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import packaged_limits_with

from armbench.bench.runner import ProgressPrinter
from armbench.bench.runner.progress import PER_SUITE, PER_TRIAL, ProgressStream

ROOT = Path(__file__).resolve().parents[1]

#: The default run, shortened: every suite, the packaged limits, a few trials each (the lines a
#: suite shows do not grow with its trials; the default run's figures are in the report).
SHORT_SUITES = """
[suites.accuracy]
laps = 1

[suites.repeatability]
cycles = 2
speeds_pct = [100]
vap_cycles = 1
path_cycles = 1

[suites.startup-recovery]
trials = 2
conditions = ["stopped-near", "stopped-far"]
wear_duration_s = 10.0

[suites.joints]
cycles = 2
"""
#: The most lines the default run may show on a terminal without ``-v`` (issue 42).
MAX_LINES = 30


class _Clock:
    """The wall clock the printer reads, moved by the test."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_ci_log_gets_a_line_per_suite_and_one_every_interval() -> None:
    """No terminal: a suite's line when it begins, then once per ``interval_s`` of wall time
    (not per trial), its last line when it ends; a trial in error is a line of its own."""
    clock = _Clock()
    log = io.StringIO()
    printer = ProgressPrinter(ProgressStream(log, PER_SUITE, interval_s=60.0), 30,
                              wall_clock=clock)
    printer.plan("a", 20)
    printer.plan("b", 10)
    printer.message("[a] 20 trial(s)")
    for k in range(1, 21):
        clock.now_s += 10.0  # 200 s of trials: a line at 60, 120, 180 s
        printer.message(f"[a] a: lap {k}")
        printer.trial("a", k, 20, "done" if k != 7 else "error (lost)", 10.0)
    printer.message("[a] done: 40 measurement(s)")
    printer.message("warning: the capture stopped")
    printer.message("[b] 10 trial(s)")
    for k in range(1, 11):
        printer.trial("b", k, 10, "done", 1.0)
    printer.finish()
    lines = log.getvalue().splitlines()
    a_lines = [line for line in lines if line.startswith("[a] [")]
    assert len(a_lines) == 1 + 3 + 1, lines  # begins, three intervals, ends
    assert a_lines[-1].endswith("done: 40 measurement(s)") and "20/20 trials" in a_lines[-1]
    assert "[a] trial 7/20 error (lost)" in lines
    assert "warning: the capture stopped" in lines
    assert [line for line in lines if line.startswith("[b] [")][-1].startswith(
        "[b] [################] 10/10 trials")
    assert len(lines) == 5 + 1 + 1 + 2, lines


def test_a_terminal_gets_one_line_per_suite_rewritten_in_place() -> None:
    clock = _Clock()
    tty = _Tty()
    printer = ProgressPrinter(ProgressStream(tty, PER_SUITE), 8, wall_clock=clock,
                              robot_clock=clock)
    printer.message("armbench run x: a, b")
    for suite in ("a", "b"):
        printer.plan(suite, 4)
    for suite in ("a", "b"):
        printer.message(f"[{suite}] 4 trial(s)")
        for k in range(1, 5):
            clock.now_s += 2.0
            printer.trial(suite, k, 4, "done", 2.0)
        printer.message(f"[{suite}] done: 8 measurement(s)")
    printer.finish()
    shown = tty.getvalue()
    lines = shown.split("\n")
    assert len(lines) == 1 + 2 + 1, lines  # the header, a line per suite, nothing after
    final = lines[1].rsplit("\r\x1b[K", 1)[-1]
    assert final.startswith("[a] [################] 4/4 trials  robot 0:08  elapsed 0:08")
    assert final.endswith("done: 8 measurement(s)")
    assert "left ~0:04" in lines[1]  # the estimate, while trials were left
    assert shown.count("\r\x1b[K") >= 2 * 6  # rewritten at each trial and message


def test_per_trial_lines_are_what_a_plain_stream_and_minus_v_get() -> None:
    for plain in (True, False):
        log = io.StringIO()
        printer = ProgressPrinter(log if plain else ProgressStream(log, PER_TRIAL), 3)
        printer.plan("a", 3)
        printer.message("[a] 3 trial(s)")
        for k in range(1, 4):
            printer.trial("a", k, 3, "done", 1.0)
        printer.finish()
        text = log.getvalue()
        assert text.count("[a] trial ") == 3 and text.startswith("[a] 3 trial(s)\n")


# -- the command ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def short_default(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The packaged limits with fewer trials per suite."""
    return packaged_limits_with(tmp_path_factory.mktemp("config") / "bench.toml", SHORT_SUITES)


def _in_pty(args: list[str], cwd: Path) -> tuple[int, str]:
    """``armbench ARGS`` with a pseudo-terminal as its stdin, stdout and stderr, as an operator
    runs it: the exit status and everything the terminal got."""
    master, slave = os.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "armbench", *args], cwd=cwd, stdin=slave,
                            stdout=slave, stderr=slave, close_fds=True)
    os.close(slave)
    chunks = []
    try:
        while True:
            try:
                data = os.read(master, 65536)
            except OSError:  # the terminal closed: the process ended
                break
            if not data:
                break
            chunks.append(data)
    finally:
        os.close(master)
        proc.wait(timeout=300)
    return proc.returncode, b"".join(chunks).decode("utf-8", "replace")


def _with_pipes(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "armbench", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300, check=False)


def test_the_default_run_on_a_terminal_fits_in_a_screen(short_default: Path,
                                                         tmp_path: Path) -> None:
    status, shown = _in_pty(["run", "--config", str(short_default), "--out", "run"], tmp_path)
    assert status == 0, shown
    lines = shown.replace("\r\n", "\n").split("\n")
    assert len(lines) < MAX_LINES, shown
    for suite in ("accuracy", "repeatability", "startup-recovery", "joints"):
        (line,) = [x for x in lines if f"[{suite}] [" in x]  # one line per suite
        assert "done:" in line.rsplit("\r\x1b[K", 1)[-1], line
    assert shown.count("\r\x1b[K") > 8  # the suites' lines were live
    assert "verdict pass" in shown


def test_a_ci_log_gets_lines_per_suite_minus_v_per_trial_minus_q_the_verdict(
        short_default: Path, tmp_path: Path) -> None:
    run = _with_pipes(["run", "--config", str(short_default), "--out", "ci"], tmp_path)
    assert run.returncode == 0, run.stderr
    lines = (run.stdout + run.stderr).splitlines()
    assert len(lines) < MAX_LINES, run.stderr
    assert "\r" not in run.stderr  # a log is never rewritten in place
    assert "trial 1/" not in run.stderr

    verbose = _with_pipes(["run", "accuracy", "--config", str(short_default), "--out", "v",
                           "-v", "--workers", "1"], tmp_path)
    assert verbose.returncode == 0, verbose.stderr
    assert "[accuracy] trial 2/2 done" in verbose.stderr
    assert "[accuracy] accuracy: lap 0 (paper)" in verbose.stderr  # the suite's own lines

    quiet = _with_pipes(["run", "accuracy", "--config", str(short_default), "--out", "q",
                         "-q", "--workers", "1"], tmp_path)
    assert quiet.returncode == 0, quiet.stderr
    assert quiet.stderr == ""
    assert quiet.stdout.splitlines() == [quiet.stdout.splitlines()[0]]
    assert "verdict pass (exit 0)" in quiet.stdout
