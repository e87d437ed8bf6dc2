"""Bad captures and bad output paths given to ``armbench calibrate`` and ``armbench twin-check``:
each is one line naming the file and what is wrong, exit status 2, no traceback, and no file of the
user's lost or overwritten (``measurements/reliability.md``, second adversarial round). Also the
compiled build loading its own calibration output."""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.bench.runner.options import JUNIT_FILE, RUNNER_FILE
from armbench.bench.runner.outputs import RUN_FILES
from armbench.cli.main import main
from armbench.drivers.capture.jsonl import CaptureError
from armbench.drivers.capture.mcap_walk import START_KEY, check_key
from armbench.drivers.capture.mcap_writer import McapCapture
from armbench.drivers.capture.part import PartWriter
from armbench.drivers.capture.read import mcap_layout, open_capture
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.record import CAPTURE_FILE, JOURNAL_FILE, REPORT_FILE, RESULTS_FILE

ROOT = Path(__file__).resolve().parents[1]
#: Small chunks, so the capture has several.
CHUNK_BYTES = 20_000


async def _moves(path: Path) -> None:
    async with Arm.connect("fake://", capture=path) as arm:
        await arm.move_joints((0.3, 0.2, -0.2, 0.1))
        await asyncio.sleep(0.2)
        await arm.move_joints((0.0, 0.0, 0.0, 0.0))


def _to_mcap(jsonl: Path, mcap: Path, offset_s: float = 0.0,
             then: tuple[Path, float] | None = None) -> Path:
    """The frames of ``jsonl`` (and those of ``then``'s at its offset) as an MCAP capture."""
    capture = McapCapture(mcap, RobotSettings(), chunk_bytes=CHUNK_BYTES)
    for src, offset in [(jsonl, offset_s), *([then] if then else [])]:
        part = mcap.with_suffix(f".{offset:g}.part")
        writer = PartWriter(part, 0.0)
        for rec in open_capture(src):
            writer.write(rec.t_s, rec.dir, rec.frame, rec.error)
        writer.close()
        capture.add_part(part, offset)
        part.unlink()
    capture.close()
    return mcap


@pytest.fixture(scope="module")
def captures(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("captures")
    jsonl = folder / "capture.jsonl"
    run_virtual(_moves(jsonl))
    return {"jsonl": jsonl, "mcap": _to_mcap(jsonl, folder / "capture.mcap")}


def _cli(*args: str | Path, code: int = 2, process: bool = False) -> str:
    """``armbench ARGS`` (in this interpreter, or with ``process`` in a fresh one): its exit
    status must be ``code``; with 2 its stderr must be one line (no traceback). Returns
    stderr."""
    argv = [str(a) for a in args]
    if process:
        done = subprocess.run([sys.executable, "-m", "armbench", *argv], cwd=ROOT,
                              capture_output=True, text=True, timeout=600, check=False)
        status, out, err = done.returncode, done.stdout, done.stderr
    else:
        out_buf, err_buf = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out_buf), contextlib.redirect_stderr(err_buf):
            status = main(argv)
        out, err = out_buf.getvalue(), err_buf.getvalue()
    assert status == code, out + err
    if code == 2:  # one line of error (a deprecation note of the option may precede it)
        lines = [x for x in err.strip().splitlines() if ": note: " not in x]
        assert len(lines) == 1, err
    return err


def _both(capture: Path, tmp_path: Path, message: str, *, process: bool = False) -> None:
    """twin-check and calibrate --capture both refuse ``capture`` with ``message``, naming it;
    calibrate writes nothing."""
    out = tmp_path / "fit" / "robot.toml"
    out.parent.mkdir(exist_ok=True)
    for args in (("twin-check", capture), ("calibrate", "--capture", capture, "--out", out)):
        err = _cli(*args, process=process)
        assert capture.name in err and message in err, err
    assert list(out.parent.iterdir()) == []


# -- captures ----------------------------------------------------------------------------------


def _chunk_offsets(data: bytes) -> list[int]:
    pos, found = 8, []
    while pos + 9 <= len(data):
        opcode, length = data[pos], int.from_bytes(data[pos + 1:pos + 9], "little")
        if opcode == 0x06:
            found.append(pos)
        if opcode == 0x0F:
            break
        pos += 9 + length
    return found


def test_flipped_bytes_in_an_mcap_chunk(captures: dict[str, Path], tmp_path: Path) -> None:
    """A byte flipped inside a chunk's compressed data: the chunk is named by its offset."""
    data = bytearray(captures["mcap"].read_bytes())
    chunks = _chunk_offsets(bytes(data))
    assert len(chunks) >= 2
    data[chunks[1] + 200] ^= 0xFF
    damaged = tmp_path / "capture.mcap"
    damaged.write_bytes(data)
    _both(damaged, tmp_path, f"chunk at byte {chunks[1]} is corrupt", process=True)


def _start_value_at(data: bytes) -> int:
    """Where the value of the capture's ``start_ns`` metadata entry begins."""
    key = len(START_KEY).to_bytes(4, "little") + START_KEY.encode()
    return data.index(key) + len(key) + 4


def test_a_flipped_digit_of_the_start_is_named(captures: dict[str, Path],
                                               tmp_path: Path) -> None:
    """The run's start is kept in a metadata record, which has no checksum: a digit of it
    flipped to another digit would move every time of the capture, so its check names it."""
    data = bytearray(captures["mcap"].read_bytes())
    at = _start_value_at(bytes(data))
    assert data[at:at + 1] == b"0"
    data[at] ^= 0x01
    damaged = tmp_path / "capture.mcap"
    damaged.write_bytes(data)
    with pytest.raises(CaptureError, match=f"{START_KEY} '1' does not match its check"):
        list(open_capture(damaged))
    _both(damaged, tmp_path, "does not match its check")


def test_a_start_without_its_check_is_read_as_before(captures: dict[str, Path],
                                                     tmp_path: Path) -> None:
    """A capture written before the start had a check (here: its key's name changed, which a
    flipped byte also does) is read as it always was."""
    data = captures["mcap"].read_bytes()
    key = check_key(START_KEY).encode()
    assert data.count(key) == 1
    older = tmp_path / "capture.mcap"
    older.write_bytes(data.replace(key, key[:-1] + b"X"))
    assert list(open_capture(older)) == list(open_capture(captures["mcap"]))


def test_a_closed_mcap_with_a_record_past_its_end(captures: dict[str, Path],
                                                  tmp_path: Path) -> None:
    """A closed file (its closing magic there) missing bytes in the middle is damage, not a
    killed run: the record that runs past the end is named."""
    data = captures["mcap"].read_bytes()
    first = _chunk_offsets(data)[0]
    damaged = tmp_path / "capture.mcap"
    damaged.write_bytes(data[:first + 100] + data[-8:])
    _both(damaged, tmp_path, f"record at byte {first} is corrupt: its length")


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_any_flipped_byte_is_read_alike_or_named(captures: dict[str, Path],
                                                 tmp_path_factory: pytest.TempPathFactory,
                                                 data: st.DataObject) -> None:
    """Flip any byte of an MCAP capture: the reader gives the same records (the byte was in
    something it does not read: an index, the summary) or a CaptureError; nothing else."""
    original = captures["mcap"].read_bytes()
    position = data.draw(st.integers(0, len(original) - 1))
    flip = data.draw(st.integers(1, 255))
    damaged = bytearray(original)
    damaged[position] ^= flip
    path = tmp_path_factory.mktemp("flip") / "capture.mcap"
    path.write_bytes(damaged)
    try:
        records = list(open_capture(path))
    except CaptureError as exc:
        assert str(exc).startswith(str(path))
    else:
        assert records == list(open_capture(captures["mcap"]))


def test_random_bytes(tmp_path: Path) -> None:
    """Random bytes named .mcap are not MCAP; named .jsonl they are not text."""
    noise = bytes((k * 151 + 7) % 256 for k in range(5000))
    (tmp_path / "noise.mcap").write_bytes(noise)
    _both(tmp_path / "noise.mcap", tmp_path, "is not an MCAP file", process=True)
    (tmp_path / "noise.jsonl").write_bytes(noise)
    _both(tmp_path / "noise.jsonl", tmp_path, "noise.jsonl:1: is not text: byte 0x9e at column 2")


def test_a_deeply_nested_line(captures: dict[str, Path], tmp_path: Path) -> None:
    lines = captures["jsonl"].read_text().splitlines()
    lines.insert(11, "[" * 100_000 + "]" * 100_000)
    deep = tmp_path / "deep.jsonl"
    deep.write_text("\n".join(lines) + "\n")
    _both(deep, tmp_path, "deep.jsonl:12: is not a capture record: JSON nested too deeply")


def test_an_endless_line(tmp_path: Path) -> None:
    """A line longer than any record is refused without being loaded whole."""
    endless = tmp_path / "endless.jsonl"
    endless.write_bytes(b"{" + b" " * (2 << 20))
    with pytest.raises(CaptureError, match=r"endless.jsonl:1: is longer than \d+ bytes"):
        list(open_capture(endless))


def test_time_reversed_captures(captures: dict[str, Path], tmp_path: Path) -> None:
    """Both commands refuse a capture whose times run backwards (calibrate used to fit it), in
    either format, naming the line or the topic."""
    records = [json.loads(x) for x in captures["jsonl"].read_text().splitlines()]
    end = records[-1]["t_s"]
    reversed_ = tmp_path / "reversed.jsonl"
    reversed_.write_text("".join(json.dumps({**r, "t_s": round(end - r["t_s"], 9)}) + "\n"
                                 for r in records))
    _both(reversed_, tmp_path, "s before the previous")
    later_first = _to_mcap(captures["jsonl"], tmp_path / "parts.mcap", offset_s=100.0,
                           then=(captures["jsonl"], 0.0))
    _both(later_first, tmp_path, "s before the previous")


def test_empty_captures(captures: dict[str, Path], tmp_path: Path) -> None:
    """An empty capture holds no traffic; a killed run's MCAP file without a complete chunk says
    so; one with a complete chunk and a half-written one still reads up to the first."""
    empty = tmp_path / "empty.jsonl"
    empty.write_bytes(b"")
    _both(empty, tmp_path, "empty.jsonl: holds no traffic")
    silent = McapCapture(tmp_path / "silent.mcap", RobotSettings())
    silent.close()
    _both(tmp_path / "silent.mcap", tmp_path, "silent.mcap: holds no traffic")
    killed = tmp_path / "killed.mcap"
    writer = McapCapture(tmp_path / "live.mcap", RobotSettings())
    part = tmp_path / "x.part"
    pw = PartWriter(part, 0.0)
    for rec in open_capture(captures["jsonl"]):
        pw.write(rec.t_s, rec.dir, rec.frame, rec.error)
    pw.close()
    writer.add_part(part)
    shutil.copyfile(tmp_path / "live.mcap", killed)  # what is on disk when the run is killed
    writer.close()
    assert mcap_layout(killed).chunks == 0 and not mcap_layout(killed).closed
    _both(killed, tmp_path, "killed.mcap: holds no complete chunk: the run was killed before "
                            "the first flush; nothing to replay")
    data = captures["mcap"].read_bytes()
    second = _chunk_offsets(data)[1]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:second + 50])
    assert mcap_layout(cut) == (1, False)
    assert 0 < len(list(open_capture(cut))) < len(list(open_capture(captures["mcap"])))


# -- output paths -----------------------------------------------------------------------------


def _user_files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@pytest.mark.parametrize("taken", ["robot.toml", "robot.json", "robot.html"])
def test_calibrate_refuses_to_overwrite(captures: dict[str, Path], tmp_path: Path,
                                        taken: str) -> None:
    """Any existing output is refused before the capture is read (a capture that does not
    exist is not even opened); --force overwrites them."""
    (tmp_path / taken).write_text("the user's\n")
    before = _user_files(tmp_path)
    err = _cli("calibrate", "--capture", tmp_path / "missing.jsonl", "--out", tmp_path)
    assert f"{tmp_path / taken} exists (give --force" in err
    assert _user_files(tmp_path) == before
    _cli("calibrate", "--capture", captures["jsonl"], "--out", tmp_path, "--force", code=0)
    assert (tmp_path / taken).read_text() != "the user's\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["robot.html", "robot.json",
                                                          "robot.toml"]  # no temporary left


def test_calibrate_port_checks_before_the_arm_moves(tmp_path: Path) -> None:
    """On a port, the observations file is an output too, refused before connecting (the port
    here cannot be reached: the error is about --out, not the port)."""
    (tmp_path / "robot.observations.json").write_text("{}")
    err = _cli("calibrate", "--port", "socket://127.0.0.1:9", "--out", tmp_path)
    assert "robot.observations.json exists" in err


def test_force_replaces_a_file_and_not_what_it_links_to(captures: dict[str, Path],
                                                        tmp_path: Path) -> None:
    """--force replaces each output atomically: a hard link to another file of the user's is
    replaced, the other file keeps its bytes (writing in place would have changed both)."""
    keep = tmp_path / "keep.toml"
    keep.write_text("the user's\n")
    os.link(keep, tmp_path / "robot.toml")
    assert main(["calibrate", "--capture", str(captures["jsonl"]), "--out",
                 str(tmp_path / "robot.toml"), "--force"]) == 0
    assert keep.read_text() == "the user's\n"
    assert (tmp_path / "robot.toml").read_text().startswith("# Robot settings fitted")


@pytest.mark.parametrize("name", ["results.toml", "report.toml"])
def test_never_over_a_run_record(captures: dict[str, Path], tmp_path: Path, name: str) -> None:
    """--out inside a run folder whose outputs would replace the record or its report: refused
    with --force too, the run's files byte for byte as they were."""
    run = tmp_path / "run"
    run.mkdir()
    for record_file in (RESULTS_FILE, REPORT_FILE):
        (run / record_file).write_text(f"the run's {record_file}\n")
    before = _user_files(run)
    for force in ((), ("--force",)):
        err = _cli("calibrate", "--capture", captures["jsonl"], "--out", run / name, *force)
        assert "belongs to the run record" in err
    assert _user_files(run) == before


def test_run_files_are_the_runs() -> None:
    assert {RESULTS_FILE, JOURNAL_FILE, REPORT_FILE, CAPTURE_FILE, JUNIT_FILE,
            RUNNER_FILE} <= RUN_FILES


def test_an_output_name_that_collides_with_its_own_outputs(captures: dict[str, Path],
                                                           tmp_path: Path) -> None:
    """``--out robot.json`` once wrote the settings, then the fit over them; --out is now a
    folder, so the outputs never collide: robot.json/ holds robot.toml, .json and .html."""
    _cli("calibrate", "--capture", captures["jsonl"], "--out", tmp_path / "robot.json", code=0)
    assert sorted(p.name for p in (tmp_path / "robot.json").iterdir()) == [
        "robot.html", "robot.json", "robot.toml"]


def _cannot_create(directory: Path) -> bool:
    try:
        with tempfile.TemporaryFile(dir=directory):
            return False
    except OSError:
        return True


def _unwritable(tmp_path: Path) -> list[Path]:
    """Directories no file can be made in, for this user: sysfs (for root too), and one
    without write permission (for anyone but root)."""
    places = [Path("/sys")] if Path("/sys").is_dir() and _cannot_create(Path("/sys")) else []
    if os.geteuid() != 0:
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o555)
        places.append(locked)
    assert places, "no unwritable directory to try"
    return places


def test_unwritable_out(captures: dict[str, Path], tmp_path: Path) -> None:
    """An --out that cannot be written (a file in the way, a path under a file, a directory
    where a file is wanted, no directory, a directory nothing can be created in) is refused
    before the capture is read, by calibrate and twin-check alike."""
    blocker = tmp_path / "blocker"
    blocker.write_text("a file\n")
    missing = tmp_path / "missing.jsonl"  # never opened: the --out check comes first
    taken = tmp_path / "taken"  # --out is a folder: its robot.toml a directory in the way
    (taken / "robot.toml").mkdir(parents=True)
    dirs = [(blocker, "is not a directory"), (blocker / "sub", "blocker is not a directory")]
    dirs += [(d / "check", f"cannot write in {d}") for d in _unwritable(tmp_path)]
    cases = [*dirs, (taken, "is a directory"),
             (blocker / "robot.toml", "blocker is not a directory")]  # the former FILE.toml
    for out, message in cases:
        err = _cli("calibrate", "--capture", missing, "--out", out)
        assert f"--out {out}" in err and message in err, err
    for out, message in dirs:
        err = _cli("twin-check", missing, "--out", out)
        assert f"--out {out}" in err and message in err, err
    assert blocker.read_text() == "a file\n"


def test_twin_check_out_keeps_a_users_files(captures: dict[str, Path], tmp_path: Path) -> None:
    """A directory holding a file the check would write (or attach its report to) is refused;
    a new nested directory is created."""
    for name in (REPORT_FILE, JUNIT_FILE, CAPTURE_FILE):
        folder = tmp_path / name.replace(".", "_")
        folder.mkdir()
        (folder / name).write_text("the user's\n")
        err = _cli("twin-check", captures["jsonl"], "--out", folder)
        assert f"{folder / name} exists" in err
        assert (folder / name).read_text() == "the user's\n"
    assert main(["twin-check", str(captures["mcap"]), "--out", str(tmp_path / "a" / "b")]) == 0
    assert (tmp_path / "a" / "b" / RESULTS_FILE).is_file()


# -- the compiled build ------------------------------------------------------------------------


@pytest.mark.slow
def test_compiled_build_loads_its_own_calibration(armbench_wheel: Path, tmp_path: Path) -> None:
    """The wheel (mypyc compiling the hot modules) loads a settings file with a geometry_error
    table, and writes the calibration page of a ``fake://`` calibration (numpy-typed fitted
    values reach the compiled physics there)."""
    if shutil.which(os.environ.get("CC", "cc")) is None:
        pytest.skip("no C compiler: a wheel build installs plain Python")
    tree = tmp_path / "installed"
    with zipfile.ZipFile(armbench_wheel) as z:
        z.extractall(tree)
    env = {k: v for k, v in os.environ.items() if k != "ARMBENCH_PURE_PYTHON"}
    env["PYTHONPATH"] = str(tree)
    hand = tmp_path / "hand.toml"
    hand.write_text("[emulator.physics.geometry_error]\nd1_m = 0.001\nd4_m = 0\n")
    out = tmp_path / "robot.toml"
    done = subprocess.run([sys.executable, "-m", "armbench", "calibrate", "--port", "fake://",
                           "--budget-s", "60", "--out", str(out)], env=env, cwd=tmp_path,
                          capture_output=True, text=True, timeout=900, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    assert out.with_suffix(".html").read_text().startswith("<!DOCTYPE html>")
    assert "[emulator.physics.geometry_error]" in out.read_text()
    probe = ("import sys; from armbench.cli.perf.hot_modules import build_name; "
             "from armbench.drivers.model.settings import load_settings; "
             "from armbench.fakes.firmware.emulator_settings import emulator_settings; "
             "print(build_name()); "
             "[print(emulator_settings(load_settings(p)).physics.geometry_error.d1_m) "
             "for p in sys.argv[1:]]")
    done = subprocess.run([sys.executable, "-c", probe, str(hand), str(out)], env=env,
                          cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    build, hand_d1, fitted_d1 = done.stdout.splitlines()
    assert build == "compiled (mypyc)"
    assert float(hand_d1) == 0.001 and abs(float(fitted_d1)) < 0.01


def test_a_damaged_capture_leaves_the_reports_traffic_section_out(
        captures: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The report of a run whose capture (without its stored tally) is damaged still renders:
    the traffic section is left out with a warning naming the damage."""
    from armbench.reports.sections.traffic import traffic_section

    data = bytearray(captures["mcap"].read_bytes())
    first, second = _chunk_offsets(bytes(data))[:2]
    data[first + 200] ^= 0xFF
    damaged = tmp_path / CAPTURE_FILE
    damaged.write_bytes(data[:second + 50])  # cut short too: no summary, no stored tally
    with caplog.at_level("WARNING"):
        assert traffic_section(damaged, tmp_path, None) is None  # type: ignore[arg-type]
    assert f"chunk at byte {first} is corrupt" in caplog.text
