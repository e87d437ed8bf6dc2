"""Everything the command line reads is checked before anything moves or the run folder exists,
and every bad file, path or port is one line on stderr with exit status 2 (issue 20; the table
in ``measurements/reliability.md`` names these tests). The CLI runs in this process
(``cli.main``) except where a real pipe is the point."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import ONE_WORKER, cli, one_line_error

import armbench.cli.main
from armbench.bench.runner import ProgressPrinter
from armbench.record import load_record

RECORDS = Path(__file__).parent / "fixtures" / "records"

#: One coordinated lap of a 4 cm square: one short accuracy trial (a few simulated seconds).
ONE_LAP = """\
spec_version = "armbench-limits/1"

[suites.accuracy]
laps = {laps}
styles = ["coordinated"]
side_m = 0.04
"""

LIMIT = """
[limits."accuracy.coordinated.lap_time_s"]
high = 60.0
unit = "{unit}"
"""




def write(path: Path, text: str | bytes) -> Path:
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text)
    return path


def deep_json(path: Path, depth: int = 100_000) -> Path:
    """A JSON document nested far beyond the parser's recursion limit."""
    return write(path, "[" * depth + "]" * depth)


@pytest.fixture
def limits(tmp_path: Path) -> Path:
    """A one-lap accuracy limits file with a limit in the right unit."""
    return write(tmp_path / "bench.toml", ONE_LAP.format(laps=2) + LIMIT.format(unit="s"))


@pytest.fixture
def finished_run(tmp_path: Path, limits: Path,
                 capsys: pytest.CaptureFixture[str]) -> Iterator[Path]:
    """A finished two-lap accuracy run (two trials) in ``tmp_path/done``."""
    out = tmp_path / "done"
    status, _, err = cli(capsys, "run", "accuracy", "--config", str(limits), "--out", str(out),
                         "--workers", "1")
    assert status == 0, err
    yield out


# --------------------------------------------------------------------------------------------
# Ports


def test_a_port_without_its_tcp_port_is_refused_before_the_run_folder_exists(
        tmp_path: Path, limits: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", "accuracy", "--config", str(limits), "--out", str(out),
                         "--port", "socket://127.0.0.1")
    one_line_error(status, err, "socket://127.0.0.1", "HOST:PORT")
    assert not out.exists()


def test_resume_does_not_reuse_a_bad_port(finished_run: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    results = finished_run / "results.json"
    doc = json.loads(results.read_text())
    doc["environment"]["port"] = "socket://127.0.0.1"
    doc["suites"]["accuracy"]["status"] = "running"  # a run to continue
    write(results, json.dumps(doc))
    before = results.read_bytes()
    status, _, err = cli(capsys, "run", "--resume", str(finished_run))
    one_line_error(status, err, "socket://127.0.0.1")
    assert results.read_bytes() == before


# --------------------------------------------------------------------------------------------
# Settings, limits and fault files


@pytest.mark.parametrize("option", ["--settings", "--config"])
@pytest.mark.parametrize("kind", ["non-utf8", "directory"])
def test_a_bad_settings_or_limits_file_is_one_line(
        tmp_path: Path, option: str, kind: str, capsys: pytest.CaptureFixture[str]) -> None:
    if kind == "directory":
        bad = tmp_path / "adir"
        bad.mkdir()
        expected = "is a directory"
    else:
        bad = write(tmp_path / "latin1.toml", "# réglages\n".encode("latin-1"))
        expected = "is not UTF-8"
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", "accuracy", option, str(bad), *ONE_WORKER, "--out",
                         str(out))
    one_line_error(status, err, str(bad), expected)
    assert not out.exists()


@pytest.mark.parametrize("content,expected", [
    ('[[faultz]]\nkind = "stall"\njoint = 1\nat_s = 0.1\n', "'faultz' is not a table"),
    (ONE_LAP.format(laps=1), "'spec_version' is not a table"),  # a limits file by mistake
    ("# nothing\n", "holds no [[faults]]"),
    ('[[faults]]\nkind = "stall"\njoint = 1\nat_s = 0.1\nduraton_s = 1\n', "duraton_s"),
])
def test_a_faults_file_that_injects_nothing_it_says_is_refused(
        tmp_path: Path, limits: Path, content: str, expected: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    faults = write(tmp_path / "faults.toml", content)
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", "accuracy", "--config", str(limits), "--out", str(out),
                         "--faults", str(faults), *ONE_WORKER)
    one_line_error(status, err, expected)
    assert not out.exists()


def test_a_limit_in_the_wrong_unit_is_refused_before_trial_0(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = write(tmp_path / "bench.toml", ONE_LAP.format(laps=1) + LIMIT.format(unit="mm"))
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", "accuracy", "--config", str(config), *ONE_WORKER, "--out",
                         str(out))
    one_line_error(status, err, 'limits."accuracy.coordinated.lap_time_s".unit', "'s'")
    assert not out.exists()  # nothing measured, nothing created


def test_an_empty_limits_file_is_a_warning_in_the_verdict(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = write(tmp_path / "bench.toml", ONE_LAP.format(laps=1))
    out = tmp_path / "r"
    status, stdout, err = cli(capsys, "run", "accuracy", "--config", str(config), "--out",
                              str(out), "--workers", "1")
    assert status == 0, err
    verdict = next(line for line in stdout.splitlines() if "verdict" in line)
    assert "pass" in verdict and "warning" in verdict and "sets no limits" in verdict
    assert "verdict" not in err  # the verdict is printed once, on stdout
    record = load_record(out / "results.json")
    assert all(m.outcome == "unjudged" for _, _, m in record.iter_measurements())


@pytest.mark.parametrize("table,key,bound", [
    ("accuracy", "laps = 100000000", "must be a whole number in [1, 1000]"),
    ("repeatability", "cycles = 100000000", "must be a whole number in [1, 1000]"),
])
def test_suite_parameters_beyond_their_bound_are_refused_at_once(
        tmp_path: Path, table: str, key: str, bound: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    config = write(tmp_path / "bench.toml",
                   f'spec_version = "armbench-limits/1"\n\n[suites.{table}]\n{key}\n')
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", table, "--config", str(config), *ONE_WORKER, "--out",
                         str(out))
    one_line_error(status, err, f"suites.{table}.{key.split()[0]}", bound)
    assert not out.exists()


def test_resume_refuses_a_suite_marked_done_with_trials_missing(
        finished_run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    results = finished_run / "results.json"
    doc = json.loads(results.read_text())
    assert doc["suites"]["accuracy"]["status"] == "done"
    doc["suites"]["accuracy"]["trials"] = doc["suites"]["accuracy"]["trials"][:1]  # hand-edited
    write(results, json.dumps(doc))
    status, _, err = cli(capsys, "run", "--resume", str(finished_run))
    one_line_error(status, err, "suites.accuracy.status", "1 of 2 trials")


# --------------------------------------------------------------------------------------------
# Records: deep JSON, compare


def test_deeply_nested_json_is_one_line_everywhere_a_record_is_read(
        tmp_path: Path, limits: Path, capsys: pytest.CaptureFixture[str]) -> None:
    deep = deep_json(tmp_path / "deep.json")
    good = str(RECORDS / "passing.json")
    one_line_error(*cli(capsys, "report", str(deep))[::2], "deep.json", "nested too deeply")
    one_line_error(*cli(capsys, "compare", str(deep), good)[::2], "nested too deeply")
    one_line_error(*cli(capsys, "compare", good, str(deep))[::2], "nested too deeply")
    out = tmp_path / "r"
    one_line_error(*cli(capsys, "run", "accuracy", "--config", str(limits), "--out", str(out),
                        "--baseline", str(deep), *ONE_WORKER)[::2], "nested too deeply")
    assert not out.exists()
    runs = tmp_path / "runs"
    (runs / "bad").mkdir(parents=True)
    deep_json(runs / "bad" / "results.json")
    status, _, err = cli(capsys, "report", "--index", str(runs))
    assert status == 0 and "Traceback" not in err, err
    assert "unreadable" in (runs / "index.html").read_text()


def test_compare_refuses_another_suite_version(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    doc = json.loads((RECORDS / "passing.json").read_text())
    doc["suites"]["accuracy"]["version"] = "0"
    older = write(tmp_path / "older.json", json.dumps(doc))
    status, _, err = cli(capsys, "compare", str(older), str(RECORDS / "passing.json"))
    one_line_error(status, err, "suites.accuracy.version", "'0'")


def test_compare_fails_a_run_that_measured_nothing(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    doc = json.loads((RECORDS / "passing.json").read_text())
    for suite in doc["suites"].values():
        suite["measurements"] = []
    empty = write(tmp_path / "empty.json", json.dumps(doc))
    status, _, err = cli(capsys, "compare", str(RECORDS / "passing.json"), str(empty))
    one_line_error(status, err, "0 compared", "missing")


def test_compare_json_into_a_closed_pipe_exits_quietly() -> None:
    """``armbench compare A B --json | head -1``: a real pipe whose reader leaves early."""
    a, b = str(RECORDS / "passing.json"), str(RECORDS / "regressed.json")
    proc = subprocess.Popen([sys.executable, "-m", "armbench", "compare", a, b, "--json"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    assert proc.stdout.readline().strip() == b"{"
    proc.stdout.close()  # what head does after its line
    err = proc.stderr.read().decode()
    status = proc.wait(timeout=60)
    assert "Traceback" not in err and "BrokenPipe" not in err, err
    assert status in (3, armbench.cli.main.EXIT_BROKEN_PIPE)  # 3 (regressed): it all fit


# --------------------------------------------------------------------------------------------
# emulate and fk


def test_emulate_on_a_port_in_use_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        status, _, err = cli(capsys, "emulate", "--tcp", f"127.0.0.1:{port}", "--duration", "1")
    one_line_error(status, err, f"127.0.0.1:{port}", "in use")


@pytest.mark.parametrize("args,expected", [
    (("emulate", "--pty", "--duration", "-1"), "--duration"),
    (("emulate", "--pty", "--duration", "nan"), "--duration"),
    (("emulate", "--tcp", "127.0.0.1:0", "--idle-timeout", "0"), "--idle-timeout"),
    (("fk", "0", "0", "0", "0", "--d4", "-5"), "--d4"),
    (("fk", "0", "0", "0", "0", "--d4", "nan"), "--d4"),
])
def test_out_of_range_numbers_on_the_command_line_are_refused(
        args: tuple[str, ...], expected: str, capsys: pytest.CaptureFixture[str]) -> None:
    status, _, err = cli(capsys, *args)
    one_line_error(status, err, expected)


# --------------------------------------------------------------------------------------------
# Progress


def test_progress_counts_a_retried_trial_once() -> None:
    """Six trials, one measured twice: the run count ends at 6/6, never 7/6."""
    printer = ProgressPrinter(None, 6)
    printer.plan("s", 6)
    for k in range(1, 7):
        if k == 3:
            printer.trial("s", k, 6, "error (x), retrying (1/1)", 1.0, retry=True)
        printer.trial("s", k, 6, "done", 1.0)
    counts = [line.split("run ")[1].split()[0] for line in printer.lines]
    assert counts == ["1/6", "2/6", "2/6", "3/6", "4/6", "5/6", "6/6"]
    assert printer.estimate_s() == 0.0
