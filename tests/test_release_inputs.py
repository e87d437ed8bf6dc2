"""Inputs of the adversarial round on the release build (``docs/reliability.md``, third round):
each bad input is one line naming it, exit status 2, before any work, and nothing of the user's
(or of the installed package) written. Real files, FIFOs and processes throughout.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from armbench.cli.main import main

ROOT = Path(__file__).resolve().parents[1]
RECORDS = ROOT / "tests" / "fixtures" / "records"
#: Seconds a command may take to refuse its input; a FIFO read before this fix blocked for ever.
REFUSE_WITHIN_S = 60


def _refused(capsys: pytest.CaptureFixture[str], *argv: str | Path) -> str:
    """Run ``armbench ARGV`` in this process: exit status 2 and one line on stderr, returned."""
    status = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert status == 2, err
    assert len(err.strip().splitlines()) == 1, err
    return err


def _refused_process(*argv: str | Path, cwd: Path = ROOT) -> str:
    """Run ``python -m armbench ARGV``: it must end within :data:`REFUSE_WITHIN_S` (a command
    blocked on a FIFO fails the test instead of hanging it) with exit status 2 and one line on
    stderr, returned."""
    try:
        done = subprocess.run([sys.executable, "-m", "armbench", *map(str, argv)], cwd=cwd,
                              capture_output=True, text=True, timeout=REFUSE_WITHIN_S,
                              check=False)
    except subprocess.TimeoutExpired:
        pytest.fail(f"armbench {' '.join(map(str, argv))} blocked for {REFUSE_WITHIN_S} s")
    assert done.returncode == 2, done.stdout + done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    return done.stderr


# --- captures ------------------------------------------------------------------------------------

@pytest.mark.parametrize("argv", [("twin-check", "{f}"), ("calibrate", "--capture", "{f}",
                                                           "--out", "{tmp}/fit")])
@pytest.mark.parametrize("name", ["capture.mcap", "capture.jsonl", "capture"])
def test_a_fifo_given_as_a_capture_is_refused_at_once(tmp_path: Path, argv: tuple[str, ...],
                                                      name: str) -> None:
    fifo = tmp_path / name
    os.mkfifo(fifo)
    err = _refused_process(*(a.format(f=fifo, tmp=tmp_path) for a in argv))
    assert f"{fifo}: is a FIFO, not a capture" in err
    assert fifo.is_fifo() and not (tmp_path / "fit").exists()


def test_a_device_given_as_a_capture_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    err = _refused(capsys, "twin-check", "/dev/zero")
    assert "/dev/zero: is a character device, not a capture" in err


@pytest.mark.parametrize("name", ["results.json", "results.journal.jsonl"])
def test_a_run_records_file_given_as_a_capture_says_so(tmp_path: Path, name: str,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    run.mkdir()
    record = run / name
    if name == "results.json":
        shutil.copy(RECORDS / "passing.json", record)
    else:  # a journal line: a finished trial of a suite
        record.write_text('{"suite": "accuracy", "trial": {"index": 0, "status": "done"}}\n')
    for argv in (("twin-check", record), ("calibrate", "--capture", record, "--out",
                                           tmp_path / "fit")):
        err = _refused(capsys, *argv)
        assert f"{record}: is a run record" in err, err
        assert "give the run's capture.mcap or capture.jsonl" in err


def test_a_run_directory_given_as_a_capture_names_its_capture(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "capture.mcap").write_bytes(b"")
    err = _refused(capsys, "twin-check", tmp_path)
    assert f"is a directory, not a capture (give {tmp_path / 'capture.mcap'})" in err


# --- settings ------------------------------------------------------------------------------------

@pytest.mark.parametrize(("value", "problem"), [
    ("1.5", "1.5 must be a whole number of encoder counts 0..64"),
    ("100000", "100000 must be a whole number of encoder counts 0..64"),
    ("-1", "-1 must be a whole number of encoder counts 0..64"),
])
def test_a_deadband_is_a_bounded_whole_number(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              value: str, problem: str) -> None:
    settings = tmp_path / "robot.toml"
    settings.write_text(f"[emulator]\ndeadband_counts = {value}\n")
    err = _refused(capsys, "run", "accuracy", "--settings", settings, "--out", tmp_path / "run")
    assert f"emulator.deadband_counts: {problem}" in err
    assert not (tmp_path / "run").exists()
