"""Link outages (issue 20): the far end of a real link killed and restarted mid-trial, over a pty
(``armbench emulate --pty``), TCP (``emulate --tcp``) and RFC 2217 through a real ser2net.

Real processes and sockets, nothing mocked. Each outage must appear in the record as an event of
the trial it hit (when, how long, why, what was lost), that trial is marked disturbed and the
verdict line says so; the trial measured before the outage keeps every figure; an outage longer
than ``[bench] outage_timeout_s`` ends the trial in ``LinkLostError`` naming the port and the
silence, never in ``MoveTimeoutError``. The driver-level cases pin the same behaviour on one move.
"""

from __future__ import annotations

import asyncio
import json
import select
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from far_end import ROOT, Emulator, emulator_maker, ser2net_over

from armbench.drivers.host.arm import Arm, ReconnectPolicy
from armbench.drivers.model.errors import LinkLostError, PortLostError
from armbench.record import load_record

TWO_LAPS = """\
spec_version = "armbench-limits/1"

[bench]
outage_timeout_s = {timeout_s}
reply_timeout_s = 5.0
connect_timeout_s = 30.0
move_timeout_scale = 10.0

[suites.accuracy]
laps = 2
styles = ["coordinated"]
side_m = 0.04
"""
"""Two coordinated laps of a 4 cm square: two trials of ~5 s in real time. The reply and
connection timeouts are a few seconds and the moves' ten times the driver's: an emulator process
starved of CPU may fall silent for longer than the defaults, and runs slower than the host's clock
(which a move's timeout measures); the outages here are made by killing the far end."""
NEAR = (0.05, 0.05, 0.05, 0.05)
"""A move whose default timeout is ~1.1 s: shorter than the outages below."""


@pytest.fixture
def emulators(tmp_path: Path) -> Iterator[Callable[..., Emulator]]:
    with emulator_maker(tmp_path) as make:
        yield make


@dataclass
class FarEnd:
    """What a test kills and restarts: the emulator, or ser2net in front of it (then the arm
    lives on through the outage: ``arm_survives``)."""

    port: str
    kill: Callable[[], None]
    start: Callable[[], None]
    arm_survives: bool


@pytest.fixture(params=[pytest.param("pty", marks=pytest.mark.slow),
                        pytest.param("tcp", marks=pytest.mark.slow), "rfc2217"])
def far_end(request: pytest.FixtureRequest, tmp_path: Path,
            emulators: Callable[..., Emulator]) -> Iterator[FarEnd]:
    kind: str = request.param
    if kind == "rfc2217":
        emu = emulators("pty")
        with ser2net_over(tmp_path, emu.link) as server:
            yield FarEnd(server.port, server.kill, server.start, True)
        return
    emu = emulators(kind)

    def kill() -> None:
        emu.stop(signal.SIGKILL)
        # the device goes with it, as udev removes an unplugged adapter's node: a stale link
        # could lead to a pty number that another process on this machine was given since
        emu.link.unlink(missing_ok=True)

    yield FarEnd(emu.port, kill, emu.start, False)


def _run_with_outage(tmp: Path, far: FarEnd, *, down_s: float | None,
                     timeout_s: float) -> tuple[int, str, Path, float]:
    """``armbench run accuracy`` (two trials) on ``far.port``; once trial 1 is done and the
    second has run for 1 s, the far end is killed and, after ``down_s`` (None: never), started
    again. The exit status, stdout + stderr, the run folder, and the seconds from the kill until
    the far end served again (a loaded machine starts a process slowly)."""
    config = tmp / "two-laps.toml"
    config.write_text(TWO_LAPS.format(timeout_s=timeout_s))
    out = tmp / "run"
    proc = subprocess.Popen([sys.executable, "-m", "armbench", "-v", "run", "accuracy", "--config",
                             str(config), "--port", far.port, "--out", str(out), "--seed", "3"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    assert proc.stdout is not None
    lines: list[str] = []
    deadline = time.monotonic() + 180.0  # a loaded machine starts Python slowly
    try:
        while not any("trial 1/2 done" in line for line in lines):
            assert time.monotonic() < deadline, "".join(lines)
            ready, _, _ = select.select([proc.stdout], [], [], 1.0)
            if ready:
                line = proc.stdout.readline()
                assert line, "".join(lines)
                lines.append(line)
        time.sleep(1.0)  # the second lap is under way
        t_kill = time.monotonic()
        far.kill()
        if down_s is not None:
            time.sleep(down_s)
            far.start()
        down_wall_s = time.monotonic() - t_kill
        rest, _ = proc.communicate(timeout=120.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    return proc.returncode, "".join(lines) + rest, out, down_wall_s


def _show(far: FarEnd, trial: Any, event: dict[str, Any], status: int) -> None:
    """One line of the campaign's outcome (shown with ``pytest -s``)."""
    print(f"\n{far.port.split(':')[0]}: exit {status}, trial {trial.index} {trial.status}"
          f"{' (' + (trial.error or '')[:60] + ')' if trial.error else ''}, disturbed "
          f"{trial.disturbed}; outage {event['duration_s']:.2f} s, "
          f"{event['reconnect_attempts']} failed reconnects, "
          f"{event['commands_unacknowledged']} commands unacknowledged, cause {event['cause']!r}")


def _lost_port_events(trial: Any) -> list[dict[str, Any]]:
    return [ev for ev in trial.events if ev["event"] == "link outage"
            and ev["kind"] == "port lost"]


def _check_first_trial_kept(out: Path) -> Any:
    """Trial 0, measured before the outage: done, undisturbed, every figure on disk (also in
    the journal-free ``results.json``)."""
    record = load_record(out / "results.json")
    first = record.suites["accuracy"].trials[0]
    assert first.status == "done" and not first.disturbed and first.events == ()
    names = {m.name for m in first.measurements}
    assert len(names) >= 10 and all(m.value == m.value for m in first.measurements)
    raw = json.loads((out / "results.json").read_text())["suites"]["accuracy"]["trials"][0]
    assert {m["name"] for m in raw["measurements"]} == names
    return record


def test_a_short_outage_mid_trial_is_recorded_and_disturbs_the_trial(
        far_end: FarEnd, tmp_path: Path) -> None:
    status, output, out, down_wall_s = _run_with_outage(tmp_path, far_end, down_s=1.0,
                                                        timeout_s=30.0)
    record = _check_first_trial_kept(out)
    second = record.suites["accuracy"].trials[1]
    (lost,) = _lost_port_events(second)
    assert second.disturbed
    # when (on the run clock, inside the trial), how long (the kill-to-restart time and the
    # reconnection), why, and what it cost
    assert 0.0 <= lost["start_t_s"] <= lost["detected_t_s"] <= lost["end_t_s"]
    assert lost["end_t_s"] <= second.duration_s + 1e-6
    assert 1.0 <= lost["duration_s"] <= down_wall_s + 5.0, (lost, down_wall_s)
    assert lost["duration_s"] == pytest.approx(lost["end_t_s"] - lost["start_t_s"])
    assert not lost["ongoing"] and lost["cause"]
    assert lost["reconnect_attempts"] >= 1 and lost["commands_unacknowledged"] >= 0
    if far_end.arm_survives:  # ser2net restarted: the lap goes on where it was
        assert second.status == "done" and status == 0 and record.verdict == "pass", output
        assert {m.name for m in second.measurements} == {
            m.name for m in record.suites["accuracy"].trials[0].measurements}
    elif second.status == "error":  # a new emulator starts at home, far from the lap: a typed
        assert second.error is not None and status == 4  # error of the arm, after the link
        assert not second.error.startswith(("bench bug", "LinkLostError", "PortLostError"))
    _show(far_end, second, lost, status)
    assert "1 trial disturbed by link outages (accuracy 1)" in output
    assert "disturbed: the link was lost 1 time(s)" in output  # the trial's progress line
    assert "1 trial disturbed by link outages" in (out / "report.html").read_text()
    assert 'name="disturbed_trials" value="1"' in (out / "junit.xml").read_text()


def test_an_outage_beyond_the_timeout_is_a_lost_port_not_a_move_timeout(
        far_end: FarEnd, tmp_path: Path) -> None:
    status, output, out, _ = _run_with_outage(tmp_path, far_end, down_s=None, timeout_s=2.0)
    assert status == 4, output  # incomplete: a trial in error
    record = _check_first_trial_kept(out)
    second = record.suites["accuracy"].trials[1]
    assert second.status == "error" and second.error is not None
    assert second.error.startswith(f"LinkLostError: {far_end.port}: link lost, silent for "), (
        second.error)
    (lost,) = _lost_port_events(second)
    assert lost["ongoing"] and lost["end_t_s"] is None and lost["reconnect_attempts"] >= 1
    # no sooner than the timeout; a loaded host may notice it later (a few seconds at most)
    assert 2.0 <= lost["duration_s"] <= 2.0 + 5.0, lost
    assert second.disturbed and "MoveTimeoutError" not in output
    _show(far_end, second, lost, status)


@pytest.fixture
def tcp_emulator(emulators: Callable[..., Emulator]) -> Emulator:
    return emulators("tcp")


def test_a_move_waits_for_the_link_and_its_deadline_moves_by_the_outage(
        tcp_emulator: Emulator) -> None:
    """The emulator killed during a move of ~1.1 s timeout and back 2 s later: the move is
    resent and arrives (no MoveTimeoutError); the outage is in ``link_outages()``."""
    emu = tcp_emulator
    policy = ReconnectPolicy(initial_delay_s=0.05, factor=1.5, max_delay_s=0.2,
                             max_attempts=None, give_up_after_s=15.0)

    async def body() -> None:
        loop = asyncio.get_running_loop()
        async with Arm.connect(emu.port, reconnect=policy, reply_timeout_s=5.0) as arm:
            t0 = loop.time()
            mover = asyncio.create_task(arm.move_joints(NEAR, 10))
            await asyncio.sleep(0.05)
            await asyncio.to_thread(emu.stop, signal.SIGKILL)
            await asyncio.sleep(2.0)
            await asyncio.to_thread(emu.start)
            state = await asyncio.wait_for(mover, 20.0)
            assert state is not None
            (outage,) = arm.link_outages(t0)
            assert outage.kind == "port lost" and outage.ended_s is not None
            assert outage.duration_s(loop.time()) >= 2.0
            assert outage.reconnect_attempts >= 1
            assert arm.link_down_s(t0) == pytest.approx(outage.duration_s(loop.time()))

    asyncio.run(asyncio.wait_for(body(), 60.0))


def test_a_link_lost_for_good_names_the_port_and_the_silence(tcp_emulator: Emulator) -> None:
    emu = tcp_emulator
    policy = ReconnectPolicy(initial_delay_s=0.05, max_delay_s=0.2, max_attempts=None,
                             give_up_after_s=2.0)

    async def body() -> None:
        loop = asyncio.get_running_loop()
        async with Arm.connect(emu.port, reconnect=policy, reply_timeout_s=5.0) as arm:
            mover = asyncio.create_task(arm.move_joints(NEAR, 10))
            await asyncio.sleep(0.05)
            t_kill = loop.time()
            await asyncio.to_thread(emu.stop, signal.SIGKILL)
            with pytest.raises(LinkLostError) as info:
                await asyncio.wait_for(mover, 10.0)
            err = info.value
            assert isinstance(err, PortLostError) and err.port == emu.port
            # no sooner than give_up_after_s; a loaded host may give up later, by seconds at most
            assert 2.0 <= err.silent_s <= 2.0 + 3.0 and err.attempts >= 1
            assert f"silent for {err.silent_s:.1f} s" in str(err)
            assert loop.time() - t_kill < 2.0 + 3.0
            (outage,) = arm.link_outages()
            assert outage.ended_s is None and outage.kind == "port lost"
            with pytest.raises(LinkLostError):  # every later call says the same
                await arm.wait_state(lambda s: True)

    asyncio.run(asyncio.wait_for(body(), 30.0))
