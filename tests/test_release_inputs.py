"""Inputs of the adversarial round on the release build (``measurements/reliability.md``, third
round): each bad input is one line naming it, exit status 2, before any work, and nothing of the
user's (or of the installed package) written. Real files, FIFOs and processes throughout.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ONE_WORKER, packaged_limits_with
from tmpfs import mounted_tmpfs

from armbench.cli.main import main
from armbench.fakes.avr.harness import FIRMWARE_SOURCE
from armbench.record import RecordError
from armbench.record.files import atomic_write_bytes

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


# --- output paths --------------------------------------------------------------------------------

def _tree(folder: Path) -> dict[str, bytes]:
    """Every file below ``folder`` (path → bytes): what must stay as it was."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


@pytest.mark.skipif(shutil.which("avr-gcc") is None, reason="no AVR toolchain")
def test_firmware_build_out_is_relative_to_the_working_directory(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A copy of the sources holding a folder named as ``--out``: the build went there (exit 0)
    or failed to find the folder the compiler, running in the sources, was given; now it goes
    where the user is, and the sources stay as they were."""
    source = tmp_path / "firmware"
    shutil.copytree(FIRMWARE_SOURCE, source)
    (source / "relout").mkdir()
    before = _tree(source)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(["firmware", "build", "--source", str(source), "--out", "relout"]) == 0
    assert {p.name for p in (work / "relout").iterdir()} >= {
        *(f"joint{n}.{ext}" for n in range(1, 5) for ext in ("elf", "hex")), "armfw-harness"}
    assert _tree(source) == before


def test_firmware_build_out_that_cannot_be_a_folder(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    afile, fifo = tmp_path / "afile", tmp_path / "fifo"
    afile.write_text("mine\n")
    os.mkfifo(fifo)
    for out, problem in ((afile, "is not a directory"), (fifo, "is not a directory"),
                         (Path("/proc/armbench-nowhere"), "cannot write in /proc"),
                         (FIRMWARE_SOURCE / "harness", "is inside the firmware sources")):
        err = _refused(capsys, "firmware", "build", "--out", out)
        assert f"--out {out}: {problem}" in err, err
    assert afile.read_text() == "mine\n" and fifo.is_fifo()
    assert not any(tmp_path.glob(".*.lock")) and not any(p.suffix == ".elf" for p in
                                                         FIRMWARE_SOURCE.rglob("*"))


def test_merge_out_is_checked_before_a_shard_is_read(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """(No shard here: the out is refused first; with real shards it was a traceback.)"""
    err = _refused(capsys, "merge", tmp_path, "--out", "/proc/armbench-merged")
    assert "--out: /proc/armbench-merged cannot be written" in err, err


def test_compare_html_never_replaces_a_fifo_or_a_folder(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """``--html /dev/null`` run as root replaced the device with a regular file (the page was
    written beside it and renamed over it); a FIFO stands in for the device here."""
    fifo = tmp_path / "page.html"
    os.mkfifo(fifo)
    records = (RECORDS / "passing.json", RECORDS / "passing.json")
    err = _refused(capsys, "compare", *records, "--html", fifo)
    assert f"--html {fifo}: {fifo} is a FIFO, not a file; it is never replaced" in err
    assert fifo.is_fifo()
    err = _refused(capsys, "compare", *records, "--html", tmp_path)
    assert "is a directory" in err
    assert capsys.readouterr().out == ""  # refused before the comparison


def test_an_atomic_write_never_replaces_a_fifo(tmp_path: Path) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(RecordError, match="is a FIFO, not a file; it is never replaced"):
        atomic_write_bytes(fifo, b"data")
    assert fifo.is_fifo() and [p.name for p in tmp_path.iterdir()] == ["fifo"]


def test_report_index_is_checked_before_any_report(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(RECORDS / "passing.json", run / "results.json")
    err = _refused(capsys, "report", run, "--index", "/proc/armbench-runs")
    assert "--index /proc/armbench-runs/index.html" in err
    assert not (run / "report.html").exists()


# --- run --summary -------------------------------------------------------------------------------

def test_a_fifo_as_the_summary_is_refused_before_the_run(tmp_path: Path) -> None:
    """It blocked after the whole run, waiting for a reader that never came."""
    fifo = tmp_path / "summary.md"
    os.mkfifo(fifo)
    err = _refused_process("run", "accuracy", "--summary", fifo, *ONE_WORKER, "--out",
                           tmp_path / "run")
    assert f"--summary {fifo}: is a FIFO" in err
    assert fifo.is_fifo() and not (tmp_path / "run").exists()


@pytest.mark.parametrize(("summary", "problem"), [
    ("{tmp}", "is a directory"),
    ("/dev/full", "is a character device"),
    ("{tmp}/missing/summary.md", "cannot be written: its folder {tmp}/missing does not exist"),
])
def test_an_unwritable_summary_is_refused_before_the_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], summary: str, problem: str) -> None:
    """Each was a traceback and exit 1 after the whole run."""
    path = summary.format(tmp=tmp_path)
    err = _refused(capsys, "run", "accuracy", "--summary", path, *ONE_WORKER, "--out",
                   tmp_path / "run")
    assert f"--summary {path}: {problem.format(tmp=tmp_path)}" in err, err
    assert not (tmp_path / "run").exists()


def test_a_summary_that_fails_after_the_run_keeps_its_status(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The disk of the summary fills during the run (a real full tmpfs): one warning line, the
    run's exit status and results as they are. The default limits over one lap per accuracy
    style (the summary is written once the run ends, whatever its length), in this process."""
    config = packaged_limits_with(tmp_path / "one-lap.toml", "[suites.accuracy]\nlaps = 1\n")
    with mounted_tmpfs(tmp_path / "disk", "size=64k") as disk:
        summary = disk / "summary.md"
        earlier = "# earlier steps\n" * 256  # a whole page: appending needs another
        summary.write_text(earlier)
        with contextlib.suppress(OSError), (disk / "filler").open("wb") as fh:
            while fh.write(bytes(4096)):
                fh.flush()
        status = main(["run", "accuracy", "--seed", "3", "--config", str(config), "--summary",
                       str(summary), *ONE_WORKER, "--out", str(tmp_path / "run")])
        err = capsys.readouterr().err
        assert summary.read_text() == earlier
    assert status == 0, err
    warning = [line for line in err.splitlines() if "--summary" in line]
    assert warning == [f"armbench run: warning: --summary {summary}: could not be written: No "
                       f"space left on device; the run's results are in {tmp_path / 'run'}"]
    assert (tmp_path / "run" / "results.json").is_file()


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


# --- a run directory's own files ---------------------------------------------------------------

@pytest.mark.parametrize(("argv", "fifo_name"), [
    (("report", "{run}"), "results.journal.jsonl"),
    (("merge", "{run}", "--out", "{tmp}/merged"), "runner.json"),
    (("run", "--resume", "{run}"), "runner.json"),
    (("campaign", "--resume", "{run}"), "runner.json"),
])
def test_a_fifo_among_a_run_directorys_files_is_refused(tmp_path: Path, argv: tuple[str, ...],
                                                        fifo_name: str) -> None:
    """A run directory is the user's: a FIFO where its journal or runner.json should be
    blocked ``report``, ``merge``, ``run --resume`` and ``campaign --resume`` for ever."""
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(RECORDS / "interrupted.json", run / "results.json")
    os.mkfifo(run / fifo_name)
    err = _refused_process(*(a.format(run=run, tmp=tmp_path) for a in argv))
    assert f"{run / fifo_name}: is a FIFO" in err, err


# --- settings ------------------------------------------------------------------------------------

@pytest.mark.parametrize(("value", "problem"), [
    ("1.5", "1.5 must be a whole number in [0, 64] encoder counts"),
    ("100000", "100000 must be a whole number in [0, 64] encoder counts"),
    ("-1", "-1 must be a whole number in [0, 64] encoder counts"),
])
def test_a_deadband_is_a_bounded_whole_number(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              value: str, problem: str) -> None:
    settings = tmp_path / "robot.toml"
    settings.write_text(f"[emulator]\ndeadband_counts = {value}\n")
    err = _refused(capsys, "run", "accuracy", "--settings", settings, *ONE_WORKER, "--out",
                   tmp_path / "run")
    assert f"emulator.deadband_counts: {problem}" in err
    assert not (tmp_path / "run").exists()
