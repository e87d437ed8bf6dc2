"""The second adversarial round on what the command line reads (the table "Second adversarial round
— inputs" of ``measurements/reliability.md`` names these tests): special files and oversized or
deeply nested TOML, records holding integers Python will not convert, times and counts beyond what
the record and the capture can store, a malformed scheduler address, a non-finite emulator seed,
``campaign`` without ``--samples``. Each is one line on stderr naming the value, exit status 2, and
no run folder created or file overwritten. The CLI runs in this process, except where the input
could block or exhaust the process (a FIFO, ``/dev/zero``): there it runs as a child with a time and
memory bound, so a regression fails instead of hanging the suite."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ONE_WORKER, cli, one_line_error

from armbench.bench.runner.plan import BENCH_BOUNDS, MAX_TRIALS
from armbench.bench.suites import SUITES
from armbench.drivers.model.settings import MAX_TOML_DEPTH
from armbench.drivers.model.user_files import MAX_TOML_BYTES
from armbench.record import load_record

ROOT = Path(__file__).resolve().parents[1]
RECORDS = Path(__file__).parent / "fixtures" / "records"
#: Python refuses to convert integers of more digits than this (``sys.int_info``).
DIGIT_LIMIT = sys.int_info.default_max_str_digits
#: The seconds field of the capture's stamps (``builtin_interfaces/Time.sec``) is an int32.
INT32_MAX = 2**31 - 1

ONE_LAP = """\
spec_version = "armbench-limits/1"

[suites.accuracy]
laps = 1
styles = ["coordinated"]
side_m = 0.04
"""




def _bounded_child() -> None:
    """Run in the child before ``exec``: at most 1 GiB of address space, so a reader that reads
    ``/dev/zero`` to its end fails with MemoryError instead of taking the machine's memory."""
    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))


def child_cli(*args: str) -> tuple[int, str]:
    """``python -m armbench ARGS`` as a child process bounded in memory and time: exit status and
    stderr. A child still reading after the deadline is killed and the test fails."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    try:
        done = subprocess.run([sys.executable, "-m", "armbench", *args], cwd=ROOT, env=env,
                              capture_output=True, text=True, timeout=180, check=False,
                              preexec_fn=_bounded_child)
    except subprocess.TimeoutExpired:
        pytest.fail(f"armbench {' '.join(args)} still blocked after 180 s")
    return done.returncode, done.stderr


def big_int_record(path: Path) -> Path:
    """A valid record but for one integer of more digits than Python converts."""
    doc = json.loads((RECORDS / "passing.json").read_text())
    doc["reference"]["huge"] = 0
    text = json.dumps(doc).replace('"huge": 0', '"huge": ' + "9" * (DIGIT_LIMIT + 100))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def nested_toml(path: Path, depth: int) -> Path:
    path.write_text("a = " + "[" * depth + "]" * depth + "\n")
    return path


# --------------------------------------------------------------------------------------------
# TOML inputs: special files, size, nesting


def _toml_args(option: str, path: Path) -> list[str]:
    """The arguments of a ``run`` that reads ``path`` as the TOML input ``option``."""
    if option.startswith("fake://"):
        return ["--port", f"fake://?{option.removeprefix('fake://')}={path}"]
    return [option, str(path)]


@pytest.mark.parametrize("option", ["--config", "--settings", "--faults", "fake://settings",
                                    "fake://faults"])
def test_a_fifo_as_a_toml_input_is_refused_without_blocking(tmp_path: Path, option: str) -> None:
    fifo = tmp_path / "input.toml"
    os.mkfifo(fifo)  # nobody ever writes to it: opening it for reading would block for ever
    out = tmp_path / "r"
    status, err = child_cli("run", "accuracy", *_toml_args(option, fifo), *ONE_WORKER, "--out",
                            str(out))
    one_line_error(status, err, str(fifo), "is a FIFO", "regular file")
    assert not out.exists()


@pytest.mark.parametrize("option", ["--config", "fake://settings"])
def test_dev_zero_as_a_toml_input_is_refused_without_reading(tmp_path: Path, option: str) -> None:
    out = tmp_path / "r"
    status, err = child_cli("run", "accuracy", *_toml_args(option, Path("/dev/zero")), *ONE_WORKER,
                            "--out", str(out))
    one_line_error(status, err, "/dev/zero", "is a character device")
    assert not out.exists()


def test_a_fifo_as_the_campaign_settings_is_refused(tmp_path: Path) -> None:
    fifo = tmp_path / "fitted.toml"
    os.mkfifo(fifo)
    out = tmp_path / "c"
    status, err = child_cli("campaign", "accuracy", "--samples", "2", "--settings", str(fifo),
                            "--out", str(out))
    one_line_error(status, err, str(fifo), "is a FIFO")
    assert not out.exists()


@pytest.mark.parametrize("option", ["--config", "--settings", "--faults"])
def test_a_toml_input_beyond_the_size_bound_is_refused(
        tmp_path: Path, option: str, capsys: pytest.CaptureFixture[str]) -> None:
    big = tmp_path / "big.toml"
    big.write_text("# padding\n" * (MAX_TOML_BYTES // 10 + 1))  # one comment line too many
    assert big.stat().st_size > MAX_TOML_BYTES
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", "accuracy", option, str(big), *ONE_WORKER, "--out",
                         str(out))
    one_line_error(status, err, str(big), f"larger than {MAX_TOML_BYTES} bytes")
    assert not out.exists()


@pytest.mark.parametrize("option", ["--config", "--settings", "--faults", "fake://settings"])
@pytest.mark.parametrize("depth", [MAX_TOML_DEPTH + 1, 100_000])
def test_a_deeply_nested_toml_input_is_one_line(
        tmp_path: Path, option: str, depth: int, capsys: pytest.CaptureFixture[str]) -> None:
    deep = nested_toml(tmp_path / "deep.toml", depth)
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", "accuracy", *_toml_args(option, deep), *ONE_WORKER, "--out",
                         str(out))
    one_line_error(status, err, str(deep), f"nested more than {MAX_TOML_DEPTH}")
    assert not out.exists()


def test_the_nesting_bound_leaves_the_formats_room(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """A settings file nested exactly to the bound is read (and refused for what it says, not
    for its depth)."""
    ok = nested_toml(tmp_path / "ok.toml", MAX_TOML_DEPTH - 1)
    status, _, err = cli(capsys, "run", "accuracy", "--settings", str(ok), *ONE_WORKER, "--out",
                         str(tmp_path / "r"))
    assert status == 2 and "nested" not in err, err


# --------------------------------------------------------------------------------------------
# Records holding an integer beyond Python's digit limit


def test_a_huge_integer_in_a_record_is_one_line_in_compare_and_report(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = big_int_record(tmp_path / "run" / "results.json")
    report = bad.parent / "report.html"
    report.write_text("the user's earlier report\n")
    good = str(RECORDS / "passing.json")
    one_line_error(*cli(capsys, "compare", str(bad), good)[::2], str(bad), "4300 digits")
    one_line_error(*cli(capsys, "compare", good, str(bad))[::2], str(bad), "4300 digits")
    one_line_error(*cli(capsys, "report", str(bad.parent))[::2], str(bad), "4300 digits")
    assert report.read_text() == "the user's earlier report\n"


def test_a_huge_integer_in_a_baseline_is_refused_before_the_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = big_int_record(tmp_path / "base" / "results.json")
    config = tmp_path / "bench.toml"
    config.write_text(ONE_LAP)
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", "accuracy", "--config", str(config), "--out", str(out),
                         "--baseline", str(bad), *ONE_WORKER)
    one_line_error(status, err, "baseline", str(bad), "4300 digits")
    assert not out.exists()


def test_a_huge_integer_in_a_shard_is_one_line_in_merge(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = big_int_record(tmp_path / "s1" / "results.json")
    (bad.parent / "runner.json").write_text('{"shard": [1, 2]}')
    out = tmp_path / "merged"
    status, _, err = cli(capsys, "merge", str(bad.parent), "--out", str(out))
    one_line_error(status, err, str(bad), "4300 digits")
    assert not out.exists()


def test_a_huge_integer_in_a_journal_names_the_journal(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "results.json").write_bytes((RECORDS / "passing.json").read_bytes())
    journal = run / "results.journal.jsonl"
    journal.write_text('{"suite": "accuracy", "trial": {"index": '
                       + "9" * (DIGIT_LIMIT + 1) + "}}\n")
    status, _, err = cli(capsys, "report", str(run))
    one_line_error(status, err, str(journal), "4300 digits")
    assert not (run / "report.html").exists()


def test_the_index_lists_a_record_with_a_huge_integer_as_unreadable(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    (runs / "good").mkdir(parents=True)
    (runs / "good" / "results.json").write_bytes((RECORDS / "passing.json").read_bytes())
    bad = big_int_record(runs / "bad" / "results.json")
    status, out, err = cli(capsys, "report", "--index", str(runs))
    assert status == 0, err
    assert "Traceback" not in err
    warnings = err.strip().splitlines()
    assert len(warnings) == 1 and "warning" in warnings[0] and str(bad) in warnings[0], err
    html = (runs / "index.html").read_text()
    assert "unreadable" in html and "4300 digits" in html
    assert out.strip() == str(runs / "index.html")


# --------------------------------------------------------------------------------------------
# Times and counts: bounded before anything moves


def _config(tmp_path: Path, table: str, line: str) -> Path:
    path = tmp_path / "bench.toml"
    path.write_text(f'spec_version = "armbench-limits/1"\n\n[{table}]\n{line}\n')
    return path


@pytest.mark.parametrize("key,value", [
    ("settle_s", "1e10"),       # crashed after trial 0: the capture's stamps are int32 seconds
    ("settle_s", "1e300"),      # OverflowError
    ("reply_timeout_s", "1e10"),
    ("connect_timeout_s", "1e10"),
    ("outage_timeout_s", "1e10"),
    ("power_timeout_s", "1e10"),
    ("move_timeout_scale", "1e10"),
    ("retries", "1000000"),
    ("workers", "1000000"),
])
def test_bench_times_and_counts_beyond_their_bound_are_refused(
        tmp_path: Path, key: str, value: str, capsys: pytest.CaptureFixture[str]) -> None:
    config = _config(tmp_path, "bench", f"{key} = {value}")
    out = tmp_path / "r"
    workers = () if key == "workers" else ONE_WORKER  # --workers would stand for the config's
    status, _, err = cli(capsys, "run", "accuracy", "--config", str(config), *workers, "--out",
                         str(out))
    whole = "a whole number " if BENCH_BOUNDS[key].whole else ""
    one_line_error(status, err, f"bench.{key}", f"must be {whole}in {BENCH_BOUNDS[key]}")
    assert not out.exists()


@pytest.mark.parametrize("flag", ["--retries", "--workers"])
def test_command_line_counts_beyond_their_bound_are_refused(
        tmp_path: Path, flag: str, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r"
    workers = () if flag == "--workers" else ONE_WORKER
    status, _, err = cli(capsys, "run", "accuracy", flag, "1000000", *workers, "--out", str(out))
    one_line_error(status, err, flag, "1000000", f"must be a whole number in "
                                                 f"{BENCH_BOUNDS[flag[2:]]}")
    assert not out.exists()


@pytest.mark.parametrize("suite,line,key,bound", [
    ("joints", "cycles = 1000000", "cycles", "must be a whole number in [2, 1000]"),
    ("joints", "targets_frac = [" + ", ".join(f"{k / 2000:.6f}" for k in range(1001)) + "]",
     "targets_frac", "2 to 1000"),
    ("startup-recovery", "wear_duration_s = 1e10", "wear_duration_s", "must be in [0, 86400] s"),
])
def test_suite_times_and_counts_beyond_their_bound_are_refused(
        tmp_path: Path, suite: str, line: str, key: str, bound: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    config = _config(tmp_path, f"suites.{suite}", line)
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", suite, "--config", str(config), *ONE_WORKER, "--out",
                         str(out))
    one_line_error(status, err, f"suites.{suite}.{key}", bound)
    assert not out.exists()


@pytest.mark.parametrize("key", ["boot_s", "loop_overhead_s", "eeprom_write_s_per_byte"])
def test_emulator_times_beyond_their_bound_are_refused(
        tmp_path: Path, key: str, capsys: pytest.CaptureFixture[str]) -> None:
    settings = tmp_path / "robot.toml"
    settings.write_text(f"[emulator]\n{key} = 1e10\n")
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", "accuracy", "--settings", str(settings), *ONE_WORKER,
                         "--out", str(out))
    one_line_error(status, err, f"emulator.{key}", "10000000000.0", "must be in [0, ")
    assert not out.exists()


def test_the_bench_bounds_keep_the_run_clock_within_the_capture_stamps() -> None:
    """Every suite planning its most trials, each followed by the longest settle and waiting out
    the longest outage, keeps the run clock far inside the int32 seconds of the stamps."""
    per_trial_s = BENCH_BOUNDS["settle_s"].high + BENCH_BOUNDS["outage_timeout_s"].high
    assert len(SUITES) * MAX_TRIALS * per_trial_s < INT32_MAX / 10


# --------------------------------------------------------------------------------------------
# Scheduler address, emulator seed, campaign samples


@pytest.mark.parametrize("command", [["run", "accuracy"],
                                     ["campaign", "accuracy", "--samples", "2"]])
def test_an_unparseable_scheduler_address_is_one_line(
        tmp_path: Path, command: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "r"
    status, _, err = cli(capsys, *command, "--scheduler", "tcp://[::1", "--out", str(out))
    one_line_error(status, err, "--scheduler", "'tcp://[::1'")
    assert not out.exists()


def test_a_non_finite_emulator_seed_is_refused_at_load(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    settings = tmp_path / "robot.toml"
    settings.write_text("[emulator]\nseed = inf\n")
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", "accuracy", "--settings", str(settings), *ONE_WORKER,
                         "--out", str(out))
    one_line_error(status, err, "emulator.seed", "inf")
    assert not out.exists()


def test_a_non_finite_value_the_record_would_keep_is_refused_on_any_port(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The settings file goes into the record whole; on a hardware port its [emulator] table is
    not read, yet a NaN anywhere in it is still no JSON."""
    settings = tmp_path / "robot.toml"
    settings.write_text("[bench]\nnote = nan\n")
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", "accuracy", "--settings", str(settings), "--port",
                         "socket://127.0.0.1:9", "--out", str(out))
    one_line_error(status, err, "bench.note", "nan")
    assert not out.exists()


def test_campaign_without_samples_says_it_is_required(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "c"
    status, _, err = cli(capsys, "campaign", "accuracy", "--out", str(out))
    one_line_error(status, err, "--samples", "required", str(MAX_TRIALS))
    assert "0 must be" not in err
    assert not out.exists()


@pytest.mark.parametrize("value", ["0", "-1", "nan", '"slow"'])
def test_a_move_timeout_scale_that_is_no_factor_is_refused(
        tmp_path: Path, value: str, capsys: pytest.CaptureFixture[str]) -> None:
    config = _config(tmp_path, "bench", f"move_timeout_scale = {value}")
    out = tmp_path / "r"
    status, _, err = cli(capsys, "run", "accuracy", "--config", str(config), *ONE_WORKER, "--out",
                         str(out))
    one_line_error(status, err, "bench.move_timeout_scale")
    assert not out.exists()


def test_the_move_timeout_scale_reaches_the_driver_of_every_trial(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``[bench] move_timeout_scale`` multiplies the driver's default move timeouts: at 0.01 no
    move of the accuracy lap can finish in time, so each trial ends in ``MoveTimeoutError``."""
    config = _config(tmp_path, "bench", "move_timeout_scale = 0.01")
    config.write_text(config.read_text() + "\n[suites.accuracy]\nlaps = 1\n"
                      'styles = ["paper"]\n')
    out = tmp_path / "r"
    cli(capsys, "run", "accuracy", "--config", str(config), *ONE_WORKER, "--out", str(out))
    record = load_record(out / "results.json")
    errors = [t.error for s in record.suites.values() for t in s.trials]
    assert errors and all(e is not None and "MoveTimeoutError" in e for e in errors), errors
