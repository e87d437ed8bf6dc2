"""Run folders and ``--resume`` against adversarial use (``measurements/reliability.md``, second
round): one writer per folder (an OS lock a killed process releases), a resumed capture equal to the
uninterrupted one after ``kill -9`` or SIGTERM, an older ``capture.jsonl`` carried into the new
capture, no code a folder names imported, and the bad inputs that used to leave a folder behind
(a transport that cannot work, a path that is not UTF-8, an ``--out`` that cannot be written, a
disk that fills up) refused in one line with exit 2.

Every run here is a real ``python -m armbench run`` process where the case is about processes
(locks, signals); the full disk is a real tmpfs of a few hundred kilobytes (skipped where this
process may not mount one).
"""

from __future__ import annotations

import contextlib
import datetime
import functools
import io
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from conftest import packaged_limits_with, run_here
from mcap.reader import make_reader
from tmpfs import mounted_tmpfs

import armbench.cli.main
from armbench.drivers.capture.jsonl import CaptureRecord, CaptureWriter
from armbench.drivers.capture.read import (
    capture_start_ns,
    iter_events,
    open_capture,
    read_attachment,
    read_joint_states,
)
from armbench.record import load_record

ROOT = Path(__file__).resolve().parents[1]
SEED = "3"
WAIT_S = 300.0
"""Upper bound of a whole accuracy run under load (it takes seconds alone)."""
SQUARE = """
[suites.accuracy]
side_m = 0.1
speed_m_s = 0.2
settle_s = 0.0
sample_period_s = 0.05
"""
"""The accuracy run of every case here, judged by the packaged limits: the default six trials
(three laps of both styles, which the kills after trial 1 or 3 of 6 count on) on a 10 cm square
at 20 cm/s, sampled every 50 ms. What a case claims of a run folder holds for any square; this
one costs half the default's 15 cm at 5 cm/s (its trials, its capture and the twin-check
replaying it) and still passes every limit."""


def _square(folder: Path) -> str:
    """The packaged limits and :data:`SQUARE` written into ``folder``: the ``--config`` of a run
    (``--resume`` reads it again from there)."""
    return str(packaged_limits_with(folder / "square.toml", SQUARE))


def _accuracy(folder: Path, out: Path, *more: str) -> list[str]:
    """``run accuracy`` of :data:`SQUARE` (written into ``folder``) and the seed into ``out``."""
    return ["run", "accuracy", "--config", _square(folder), "--out", str(out), "--seed", SEED,
            *more]


def _env(**extra: str) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(ROOT), **extra}


def _bench(*args: str, cwd: Path = ROOT, env: dict[str, str] | None = None
           ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "armbench", *args], cwd=cwd, text=True,
                          capture_output=True, timeout=WAIT_S, check=False,
                          env=env if env is not None else _env())


def _start(*args: str) -> subprocess.Popen[str]:
    """A run in a process group of its own (its worker processes with it), showing a line per
    trial (``-v``: what the test waits for)."""
    return subprocess.Popen([sys.executable, "-m", "armbench", "-v", *args], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env(),
                            start_new_session=True)


STOP_S = 30.0
"""Bound on a SIGSTOP taking effect in each process of a run: a hung kernel, not a slow host."""


def _group_states(pgid: int) -> list[str]:
    """The state letter (``/proc/PID/stat``: R, S, D, T, Z, ...) of each process of the group
    ``pgid``."""
    states = []
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            stat = Path(entry.path, "stat").read_text(encoding="ascii")
        except OSError:  # ended meanwhile
            continue
        state, _, group = stat.rpartition(")")[2].split()[:3]  # after the command's name
        if int(group) == pgid:
            states.append(state)
    return states


def _freeze(proc: subprocess.Popen[str], sig: signal.Signals) -> None:
    """SIGSTOP or SIGCONT to the run and its workers. A stop returns once every process of the
    run has stopped: a signal takes effect when its process next leaves the kernel, so a worker
    busy on the other CPU may still finish writing its capture part after ``killpg`` returns."""
    os.killpg(proc.pid, sig)
    if sig != signal.SIGSTOP:
        return
    deadline = time.monotonic() + STOP_S
    while any(state not in "TtZX" for state in _group_states(proc.pid)):
        assert time.monotonic() < deadline, _group_states(proc.pid)
        time.sleep(0.005)


def _wait_for(proc: subprocess.Popen[str], text: str) -> None:
    """Read the process's progress until a line holds ``text`` (it is still running then)."""
    assert proc.stderr is not None
    for line in proc.stderr:
        if text in line:
            return
    pytest.fail(f"the run ended before {text!r}")


def _one_line_error(result: subprocess.CompletedProcess[str], *needles: str) -> str:
    assert result.returncode == 2, (result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("armbench run: error: "), result.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


@dataclass(frozen=True)
class Capture:
    run: Path
    frames: list[CaptureRecord]
    events: list[tuple[str, str, int, int]]
    truth: list[tuple[float, tuple[float, ...]]]
    """The arm's true joints beside the replies (``/joint_states/true``), on the run clock."""
    arm: tuple[str, Any]
    """The port and the settings of the record the capture attaches: what the twin-check builds
    the arm's actual model from. With the frames and the truth, all the twin-check reads of a
    capture (besides its own settings and limits, the defaults here): two captures equal in
    these three have the same twin-check."""

    @functools.cached_property
    def twin(self) -> dict[str, Any]:
        """``armbench twin-check --json`` of the capture, in this process (the capture is the
        case here, not the command's process): it replays the capture, seconds of CPU, so only
        where a test asks (the whole run's, checked once, serves every test of the module)."""
        out, capture = io.StringIO(), str(self.run / "capture.mcap")
        with contextlib.redirect_stdout(out):
            status = armbench.cli.main.main(["twin-check", "--json", capture])
        assert status in (0, 1), out.getvalue()
        result: dict[str, Any] = json.loads(out.getvalue())
        return result


def _capture(run: Path) -> Capture:
    path = run / "capture.mcap"
    start_ns = capture_start_ns(path)  # event stamps are on the wall clock: the run's start on
    events = [(e.kind, e.suite, e.trial,  # the run clock, which resumed runs must equal
               e.stamp.sec * 1_000_000_000 + e.stamp.nanosec - start_ns)
              for e in iter_events(path)]
    attached = read_attachment(path, "results.json")
    assert attached is not None, "the capture attaches no record"
    environment = json.loads(attached)["environment"]
    return Capture(run, list(open_capture(path)), events, read_joint_states(path),
                   (environment["port"], environment["settings"]))


@pytest.fixture(scope="module")
def whole_run(tmp_path_factory: pytest.TempPathFactory) -> Capture:
    """An uninterrupted ``run accuracy`` of :data:`SQUARE` and the seed: what every resumed run
    must equal."""
    tmp = tmp_path_factory.mktemp("whole")
    out = tmp / "run"
    done = run_here(*_accuracy(tmp, out))
    assert done.returncode == 0, done.stderr
    return _capture(out)


# -- one writer per run folder ------------------------------------------------------------------


def test_resume_of_a_run_still_going_is_refused_and_the_run_completes(
        tmp_path: Path, whole_run: Capture) -> None:
    """The run is frozen (SIGSTOP) mid-way, holding its folder: ``--resume`` of it exits 2 with
    one line naming the holder, and changes nothing; the run, continued, ends as a whole run."""
    out = tmp_path / "run"
    proc = _start(*_accuracy(tmp_path, out))
    try:
        _wait_for(proc, "trial 2/6 done")
        _freeze(proc, signal.SIGSTOP)
        before = _snapshot(out)
        refused = _bench("run", "--resume", str(out))
        line = _one_line_error(refused, f"pid {proc.pid}", "accuracy", "started")
        assert "is being written by" in line
        assert _snapshot(out) == before
    finally:
        _freeze(proc, signal.SIGCONT)
        _, err = proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 0, err
    assert not (out / ".armbench.lock").exists()
    resumed = _capture(out)
    assert len(resumed.frames) == len(whole_run.frames)
    assert resumed.events == whole_run.events


def test_a_second_run_into_the_same_out_is_refused(tmp_path: Path) -> None:
    """Two runs given one ``--out``: the second is refused before it writes anything."""
    out = tmp_path / "run"
    proc = _start(*_accuracy(tmp_path, out))
    try:
        _wait_for(proc, "trial 1/6 done")
        _freeze(proc, signal.SIGSTOP)
        before = _snapshot(out)
        # results.json is there: refused by the record check; the lock refuses without it too
        (out / "results.json").rename(out / "held.json")
        refused = _bench("run", "accuracy", "--out", str(out))
        (out / "held.json").rename(out / "results.json")
        _one_line_error(refused, f"pid {proc.pid}")
        assert _snapshot(out) == before
    finally:
        _freeze(proc, signal.SIGCONT)
        proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 0


def test_a_killed_holder_leaves_no_lock(tmp_path: Path) -> None:
    """The lock is the OS's: ``kill -9`` of its holder releases it, and the resume goes on."""
    out = tmp_path / "run"
    proc = _start(*_accuracy(tmp_path, out, "--workers", "1"))
    _wait_for(proc, "trial 1/6 done")
    os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=WAIT_S)
    resumed = run_here("run", "--resume", str(out))
    assert resumed.returncode == 0, resumed.stderr


def test_resume_of_a_fleet_being_written_is_refused(tmp_path: Path) -> None:
    """A fleet's folder is locked as a run's is: with its lock held by another process,
    ``run --resume FLEET`` is refused naming that process, and the fleet's files are unchanged."""
    fleet = tmp_path / "fleet"
    one_lap = Path(_square(tmp_path))  # what is refused depends on neither square nor laps
    one_lap.write_text(one_lap.read_text(encoding="utf-8") + "laps = 1\n", encoding="utf-8")
    done = run_here("run", "accuracy", "--port", "a=fake://?seed=1", "--port", "b=fake://?seed=2",
                    "--out", str(fleet), "--workers", "1", "--config", str(one_lap))
    assert done.returncode == 0, done.stderr
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys\n"
         "from armbench.bench.runner.lock import hold_run_folder\n"
         f"with hold_run_folder({str(fleet)!r}):\n"
         "    print('held', flush=True)\n"
         "    sys.stdin.readline()\n"],
        cwd=ROOT, env=_env(), text=True, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "held\n"
        before = _snapshot(fleet)
        refused = _bench("run", "--resume", str(fleet))
        _one_line_error(refused, f"pid {holder.pid}", "is being written by")
        assert _snapshot(fleet) == before
    finally:
        holder.communicate("\n", timeout=WAIT_S)
    assert not (fleet / ".armbench.lock").exists()


# -- a resumed capture equals the uninterrupted one ---------------------------------------------


@pytest.mark.parametrize(("sig", "after", "workers", "replayed"), [
    (signal.SIGKILL, 1, "2", True), (signal.SIGKILL, 3, "2", False),
    (signal.SIGTERM, 1, "2", False), (signal.SIGTERM, 3, "2", False),
    (signal.SIGKILL, 3, "1", True), (signal.SIGKILL, 5, "2", False)],
    ids=["SIGKILL-1", "SIGKILL-3", "SIGTERM-1", "SIGTERM-3", "SIGKILL-3-in-turn",
         "SIGKILL-5-last-in-turn"])
def test_resumed_capture_after_a_kill_equals_the_whole_run(
        sig: signal.Signals, after: int, workers: str, replayed: bool, tmp_path: Path,
        whole_run: Capture) -> None:
    """Killed after some trials (their workers' parts left behind, written out of turn; or the
    parts of trials measured in turn), then resumed: the same frames in time order, every trial
    event, the same twin-check. The check itself runs on the resumed capture where it is
    ``replayed``: after the first trial (the most of the run resumed), and in turn, whose truth
    is sampled at other moments than the whole run's (one worker carries the sampling's phase
    from trial to trial; a resumed session starts it afresh). So is a single trial left to the
    resumed session, measured in turn (``ParallelTrials.usable``), as happens when the signal
    lands late, on a loaded machine, after the workers' next trials were recorded. Elsewhere
    the capture gives it the same input (:class:`Capture`), so the same check."""
    out = tmp_path / "run"
    proc = _start(*_accuracy(tmp_path, out, "--workers", workers))
    _wait_for(proc, f"trial {after}/6 done")
    proc.send_signal(sig)
    proc.communicate(timeout=WAIT_S)
    assert proc.returncode == -sig
    recorded = load_record(out / "results.json").suites["accuracy"].trials
    replayed = replayed or sum(t.status == "done" for t in recorded) == 5
    resumed = run_here("run", "--resume", str(out))
    assert resumed.returncode == 0, resumed.stderr
    got = _capture(out)
    times = [r.t_s for r in got.frames]
    assert times == sorted(times)
    # one time base over both sessions: the wall clock of the run's (first) start
    created = json.loads((out / "results.json").read_text())["created"]
    start_ns = capture_start_ns(out / "capture.mcap")
    assert abs(start_ns / 1e9 - datetime.datetime.fromisoformat(created).timestamp()) < 1e-3
    assert len(got.frames) == len(whole_run.frames)
    assert got.frames == whole_run.frames
    assert got.events == whole_run.events
    assert sum(1 for e in got.events if e[0] in ("trial_start", "trial_end")) == 12
    assert whole_run.twin["verdict"] == "pass"
    if replayed:
        assert got.twin["verdict"] == whole_run.twin["verdict"]
        assert got.twin["rms_counts"] == whole_run.twin["rms_counts"]
    else:  # what it reads of a capture besides the frames, equal above
        assert got.truth == whole_run.truth, _first_difference(got.truth, whole_run.truth)
        assert got.arm == whole_run.arm
    assert not list(out.glob(".capture.part*"))


def test_a_run_killed_while_attaching_its_record_is_finished_by_resume(
        tmp_path: Path, whole_run: Capture) -> None:
    """Killed after its last trial was in the capture, while the record was being attached (the
    capture cut where its first attachment begins, as the kill leaves it): ``--resume`` has no
    trial left to run and used to leave the capture so, without the record twin-check reads
    the arm from. It now finishes the capture: the record attached, the same frames and events
    as the uninterrupted run. (In the killed-run test above, a signal landing that late on a
    loaded machine failed it.)"""
    out = tmp_path / "run"
    done = run_here(*_accuracy(tmp_path, out))
    assert done.returncode == 0, done.stderr
    capture = out / "capture.mcap"
    with capture.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.attachment_indexes
    with capture.open("r+b") as f:
        f.truncate(min(a.offset for a in summary.attachment_indexes))
    assert read_attachment(capture, "results.json") is None
    resumed = run_here("run", "--resume", str(out))
    assert resumed.returncode == 0, resumed.stderr
    got = _capture(out)
    assert got.frames == whole_run.frames
    assert got.events == whole_run.events
    assert got.arm == whole_run.arm


def _first_difference(got: list[tuple[float, tuple[float, ...]]],
                      want: list[tuple[float, tuple[float, ...]]]) -> str:
    """Where two lists of truth samples part, with the samples around it: what pytest's diff of
    two lists of hundreds cuts off."""
    k = next((i for i, (a, b) in enumerate(zip(got, want, strict=False)) if a != b),
             min(len(got), len(want)))
    return (f"{len(got)} samples against {len(want)}; the first difference at {k}: "
            f"{got[max(0, k - 2):k + 3]} against {want[max(0, k - 2):k + 3]}")


def test_a_resumed_legacy_capture_keeps_its_frames(tmp_path: Path, whole_run: Capture) -> None:
    """A run whose capture is an older ``capture.jsonl`` (interrupted, then resumed by this
    armbench): the new ``capture.mcap`` holds the old session's frames and the new ones."""
    out = tmp_path / "run"
    # in turn (one worker): the line comes when the trial is done, four are still to run
    proc = _start(*_accuracy(tmp_path, out, "--workers", "1"))
    _wait_for(proc, "trial 2/6 done")
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 130
    old = list(open_capture(out / "capture.mcap"))
    assert 0 < len(old) < len(whole_run.frames)
    legacy = CaptureWriter(out / "capture.jsonl", 0.0)
    for r in old:
        legacy.write(r.t_s, r.dir, r.frame, r.error)
    legacy.close()
    (out / "capture.mcap").unlink()
    kept = (out / "capture.jsonl").read_bytes()
    resumed = run_here("run", "--resume", str(out))
    assert resumed.returncode == 0, resumed.stderr
    frames = list(open_capture(out / "capture.mcap"))
    assert len(frames) == len(whole_run.frames)
    assert [(r.dir, r.frame) for r in frames] == [(r.dir, r.frame) for r in whole_run.frames]
    assert [r.t_s for r in frames] == pytest.approx([r.t_s for r in whole_run.frames], abs=1e-6)
    assert (out / "capture.jsonl").read_bytes() == kept  # the user's file, untouched


# -- a run folder cannot make armbench run its code ---------------------------------------------


def _interrupted_run(tmp_path: Path) -> Path:
    out = tmp_path / "run"
    proc = _start(*_accuracy(tmp_path, out, "--workers", "1"))
    _wait_for(proc, "trial 1/6 done")
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=WAIT_S)
    assert proc.returncode == 130
    return out


def test_resume_imports_no_module_the_folder_names(tmp_path: Path) -> None:
    """``runner.json`` naming ``this:Nope`` (the Zen of Python on import) or a module beside the
    folder: exit 2 naming it, nothing imported, nothing written."""
    out = _interrupted_run(tmp_path)
    marker = tmp_path / "pwned"
    (out / "pwn_suite.py").write_text(f"open({str(marker)!r}, 'w').write('ran')\n"
                                      "class PwnSuite: pass\n")
    info = json.loads((out / "runner.json").read_text())
    for ref in ("this:Nope", "pwn_suite:PwnSuite"):
        info["suites"] = {"accuracy": ref}
        (out / "runner.json").write_text(json.dumps(info))
        before = _snapshot(out)
        refused = _bench("run", "--resume", ".", cwd=out)
        _one_line_error(refused, repr(ref), "not registered")
        assert "Zen of Python" not in refused.stdout + refused.stderr
        assert "Beautiful is better" not in refused.stdout + refused.stderr
        assert not marker.exists()
        assert _snapshot(out) == before


def test_campaign_resume_imports_no_module_the_folder_names(tmp_path: Path) -> None:
    """``armbench campaign --resume`` reads its suite from ``runner.json`` too."""
    out = tmp_path / "campaign"
    done = run_here("campaign", "startup-recovery", "--samples", "2", "--workers", "1", "--out",
                    str(out))
    assert done.returncode == 0, done.stderr
    info = json.loads((out / "runner.json").read_text())
    info["campaign"]["suite"] = "this:Nope"
    (out / "runner.json").write_text(json.dumps(info))
    before = _snapshot(out)
    refused = _bench("campaign", "--resume", str(out))
    assert refused.returncode == 2, refused.stderr
    assert "'this:Nope'" in refused.stderr and "not registered" in refused.stderr
    assert "Beautiful is better" not in refused.stdout + refused.stderr
    assert _snapshot(out) == before


def test_resume_loads_a_suite_registered_in_the_package(tmp_path: Path) -> None:
    """The recorded reference of a registered suite (name or its module:Class) still loads."""
    out = _interrupted_run(tmp_path)
    info = json.loads((out / "runner.json").read_text())
    info["suites"] = {"accuracy": "armbench.bench.suites.accuracy:AccuracySuite"}
    (out / "runner.json").write_text(json.dumps(info))
    assert run_here("run", "--resume", str(out)).returncode == 0


# -- inputs refused before any folder exists ----------------------------------------------------


def test_labgrid_without_labgrid_is_refused_before_a_folder_exists(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "labgrid", None)  # what an environment without it gives
    out = tmp_path / "run"
    status = armbench.cli.main.main(["run", "accuracy", "--port", "labgrid://bench-1",
                                      "--out", str(out)])
    err = capsys.readouterr().err
    assert status == 2 and "labgrid is not installed" in err and len(err.splitlines()) == 1
    assert not out.exists()


def test_avr_without_firmware_sources_is_refused_before_a_folder_exists(tmp_path: Path) -> None:
    """An installed armbench has no ``firmware/`` beside it: a copy of the package without it,
    and no cached build."""
    tree = tmp_path / "site"
    package = tree / "armbench"  # laid out as setup.py installs it, less firmware/
    shutil.copytree(ROOT / "api", package, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("bench", "cli", "drivers", "fakes", "frontends", "metrics", "record", "reports"):
        shutil.copytree(ROOT / name, package / name, ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path / "run"
    refused = _bench("run", "accuracy", "--port", "avr://", "--out", str(out), cwd=tmp_path,
                     env={**os.environ, "PYTHONPATH": str(tree),
                          "XDG_CACHE_HOME": str(tmp_path / "cache")})
    _one_line_error(refused, "avr://", "no firmware sources")
    assert not out.exists()


def test_a_config_path_that_is_not_utf8_is_refused_naming_it(tmp_path: Path) -> None:
    config = os.fsdecode(os.fsencode(tmp_path) + b"/limits-\xff.toml")
    shutil.copy(ROOT / "record" / "default_bench.toml", config)
    out = tmp_path / "run"
    refused = _bench("run", "accuracy", "--config", config, "--out", str(out), cwd=tmp_path)
    _one_line_error(refused, "--config", "limits-\\xff.toml", "not valid UTF-8")
    assert not out.exists() and not (tmp_path / "runs").exists()


@pytest.mark.parametrize("case", ["file in the way", "under a file", "read-only"])
def test_an_unwritable_out_is_refused_in_one_line(case: str, tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("mine\n")
    with contextlib.ExitStack() as stack:
        if case == "file in the way":
            out = blocker
        elif case == "under a file":
            out = blocker / "run"
        else:
            out = stack.enter_context(mounted_tmpfs(tmp_path / "ro", "ro", "size=64k")) / "run"
        refused = _bench("run", "accuracy", "--out", str(out))
        line = _one_line_error(refused, "--out")
        assert {"file in the way": "a file, not a directory",
                "under a file": "a file, not a directory",
                "read-only": "read-only file system"}[case] in line
        assert not out.exists() or out == blocker
    assert blocker.read_text() == "mine\n"


FULL_DISK_KB = 240
"""A disk the run of :data:`SQUARE` fills after two or three trials (its folder takes twice that
by the end)."""


def test_a_full_disk_says_so_and_keeps_what_was_measured(tmp_path: Path,
                                                         whole_run: Capture) -> None:
    """A tmpfs too small for the run: the record's own error in one line (not the capture's
    OSError), exit 2, and the trials measured until then still on disk for ``--resume``, with
    the capture parts the full disk kept out of ``capture.mcap``: moved to a disk with room
    and resumed, the run ends with the whole run's capture."""
    moved = tmp_path / "moved"
    with mounted_tmpfs(tmp_path / "small", f"size={FULL_DISK_KB}k") as disk:
        out = disk / "run"
        full = _bench(*_accuracy(tmp_path, out))
        assert full.returncode == 2, full.stderr
        assert "Traceback" not in full.stderr
        line = full.stderr.strip().splitlines()[-1]
        assert line.startswith("armbench run: error: "), full.stderr
        assert "results" in line and "No space left on device" in line
        record = load_record(out / "results.json")
        trials = [t for s in record.suites.values() for t in s.trials]
        # what was measured is kept; a trial whose worker met the full disk is an error trial
        # (re-run by the resume below), never a half-written one
        assert any(t.status == "done" for t in trials)
        assert all(t.status == "done" or (t.status == "error" and t.error is not None
                                          and "No space left on device" in t.error)
                   for t in trials), [(t.status, t.error) for t in trials]
        errored = sorted((name, t.index) for name, s in record.suites.items() for t in s.trials
                         if t.status == "error")
        shutil.copytree(out, moved)
    resumed = run_here("run", "--resume", str(moved))
    assert resumed.returncode == 0, resumed.stderr
    got = _capture(moved)
    assert got.frames == whole_run.frames
    # the capture holds every attempt the record holds: an error trial measured again keeps its
    # own start and end (in its slot, before the new attempt's); less those, the whole run
    superseded = [(name, t.index) for name, s in load_record(moved / "results.json").suites.items()
                  for t in s.superseded_trials]
    assert sorted(superseded) == errored  # each error trial measured again, once
    assert _without_first_attempts(got.events, superseded) == whole_run.events


def _without_first_attempts(events: list[tuple[str, str, int, int]],
                            superseded: list[tuple[str, int]]) -> list[tuple[str, str, int, int]]:
    """``events`` less the first start and end of each trial in ``superseded``; each must be
    there, followed by the attempt that replaced it."""
    kept = list(events)
    for suite, index in superseded:
        for kind in ("trial_start", "trial_end"):
            at = [i for i, e in enumerate(kept) if e[:3] == (kind, suite, index)]
            assert len(at) == 2, (kind, suite, index, kept)
            del kept[at[0]]
    return kept
