"""Traffic capture: the JSON Lines writer (batched, bounded), the reader, and replaying a recorded
run into a fresh emulator (``fake://`` on virtual time) to the same final position."""

from __future__ import annotations

import asyncio
import json
import tempfile
from collections.abc import Awaitable
from pathlib import Path
from typing import TypeVar

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.drivers.capture.jsonl import (
    CaptureError,
    CaptureRecord,
    CaptureWriter,
    read_capture,
)
from armbench.drivers.capture.read import replay_capture
from armbench.drivers.host.arm import Arm, JointState
from armbench.drivers.model.protocol import Command
from armbench.fakes.clock.vclock import run_virtual

T = TypeVar("T")
COMMAND = Command.from_rad([0.1, 0.2, -0.3, 0.4], 50).encode().decode()
REPLY = "$01000,02000,59832,04000#"


async def within(aw: Awaitable[T], timeout_s: float = 20.0) -> T:
    async with asyncio.timeout(timeout_s):
        return await aw


def test_writer_batches_and_bounds_memory(tmp_path: Path) -> None:
    path = tmp_path / "c.jsonl"
    w = CaptureWriter(path, t0_s=100.0, batch_records=64, batch_interval_s=1e9)
    most = 0
    for i in range(1000):
        w.write(100.0 + i * 1e-3, "in" if i % 2 else "out", REPLY if i % 2 else COMMAND, None)
        most = max(most, w.buffered)
    assert most == 63 and w.batches == 1000 // 64
    assert len(path.read_text().splitlines()) == 64 * (1000 // 64)  # written batch by batch
    w.write(102.0, "in", "$12#", "1 fields where a reply has 4")
    w.close()
    w.close()
    w.write(103.0, "in", REPLY, None)  # ignored once closed
    records = list(read_capture(path))
    assert len(records) == w.records == 1001
    assert records[0] == CaptureRecord(0.0, "out", COMMAND, None)
    assert records[1].t_s == pytest.approx(1e-3) and records[1].dir == "in"
    assert records[-1] == CaptureRecord(2.0, "in", "$12#", "1 fields where a reply has 4")
    for line in path.read_text().splitlines():
        assert set(json.loads(line)) == {"t_s", "dir", "frame", "error"}


def test_writer_flushes_on_time(tmp_path: Path) -> None:
    path = tmp_path / "c.jsonl"
    w = CaptureWriter(path, t0_s=0.0, batch_records=1000, batch_interval_s=1.0)
    w.write(0.1, "out", COMMAND, None)
    w.write(0.5, "in", REPLY, None)
    assert path.read_text() == ""
    w.write(1.2, "in", REPLY, None)  # a second after the last flush: written now
    assert len(path.read_text().splitlines()) == 3 and w.buffered == 0
    w.close()


def test_reader_errors_name_file_and_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.jsonl"
    good = json.dumps({"t_s": 0.0, "dir": "out", "frame": COMMAND, "error": None})
    for bad, match in (("{not json", "is not JSON"),
                       (json.dumps({"t_s": "x", "dir": "in", "frame": "", "error": None}),
                        "t_s"),
                       (json.dumps({"t_s": 1.0, "dir": "up", "frame": "", "error": None}),
                        "dir"),
                       (json.dumps([1, 2]), "not a JSON object")):
        path.write_text(good + "\n\n" + bad + "\n")
        with pytest.raises(CaptureError, match=match) as info:
            list(read_capture(path))
        assert info.value.line == 3 and info.value.path == str(path)
    with pytest.raises(CaptureError, match=r"missing\.jsonl: does not exist"):
        list(read_capture(tmp_path / "missing.jsonl"))
    with pytest.raises(CaptureError, match="cannot write"):
        CaptureWriter(tmp_path / "no" / "dir" / "c.jsonl", 0.0)


def test_replay_capture_yields_commands_with_relative_times(tmp_path: Path) -> None:
    path = tmp_path / "c.jsonl"
    hold = Command.from_rad([0.0] * 4, 0).encode().decode()
    lines = [(0.5, "in", REPLY, None), (1.0, "out", COMMAND, None),
             (1.2, "in", "$xx#", "joint 1 position b'xx' is not 5 digits"),
             (1.25, "out", "$0000", "frame cut short"), (1.5, "out", hold, None)]
    path.write_text("".join(json.dumps({"t_s": t, "dir": d, "frame": f, "error": e}) + "\n"
                            for t, d, f, e in lines))
    items = list(replay_capture(path))
    assert [(i.t_s, i.capture_t_s) for i in items] == [(0.0, 1.0), (0.5, 1.5)]
    assert [i.command.encode().decode() for i in items] == [COMMAND, hold]
    path.write_text(json.dumps({"t_s": 0, "dir": "out", "frame": REPLY, "error": None}) + "\n")
    with pytest.raises(CaptureError, match="is not one command"):
        list(replay_capture(path))


async def _record(port: str, capture: Path, stop_mid_move: bool) -> tuple[JointState, tuple[
        float, ...]]:
    async with Arm.connect(port, capture=capture) as arm:
        await within(arm.move_joints([0.2, 0.1, -0.2, 0.3], 90, coordinated=True))
        await within(arm.move_to((0.35, 0.1, 0.7)))
        if stop_mid_move:
            await within(arm.move_joints([-0.3, 0.3, 0.3, -0.2], 99, wait=False))
            await within(asyncio.sleep(0.37))
            await within(arm.stop())
        await within(asyncio.sleep(0.2))
        truth = arm.ground_truth()
        assert truth is not None
        return arm.state, truth.true_rad


async def _replay(port: str, capture: Path, align: str, delay_s: float) -> tuple[
        JointState, tuple[float, ...], int]:
    async with Arm.connect(port) as arm:
        await within(asyncio.sleep(delay_s))
        n = await within(arm.replay(capture, align=align))  # type: ignore[arg-type]
        while True:  # the replay returns once the last command is sent: wait until still
            before = arm.state
            await within(asyncio.sleep(0.1))
            if arm.state.ticks == before.ticks:
                break
        truth = arm.ground_truth()
        assert truth is not None
        return arm.state, truth.true_rad, n


def test_replay_into_a_fresh_emulator_reaches_the_same_position(tmp_path: Path) -> None:
    cap = tmp_path / "arrive.jsonl"
    final, truth = run_virtual(within(_record("fake://", cap, stop_mid_move=False), 60.0))
    commands = len(list(replay_capture(cap)))
    assert commands == 2
    # replayed later and at another phase of the firmware's loop: the same final position
    again, truth2, n = run_virtual(within(_replay("fake://", cap, "first", 0.1234), 60.0))
    assert n == commands
    assert again.ticks == final.ticks
    assert all(abs(a - b) < 1e-9 for a, b in zip(truth, truth2, strict=True))


def test_replay_aligned_to_the_connection_reproduces_a_stop_mid_move(tmp_path: Path) -> None:
    cap = tmp_path / "stop.jsonl"
    final, truth = run_virtual(within(_record("fake://", cap, stop_mid_move=True), 60.0))
    assert len(list(replay_capture(cap))) == 4
    again, truth2, n = run_virtual(within(_replay("fake://", cap, "connect", 0.0), 60.0))
    assert n == 4
    assert again.ticks == final.ticks  # stopped at the very same step
    assert all(abs(a - b) < 1e-9 for a, b in zip(truth, truth2, strict=True))
    with pytest.raises(ValueError):
        run_virtual(within(_replay("fake://", cap, "sideways", 0.0), 60.0))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 2e5, allow_nan=False),
                          st.sampled_from(["in", "out"]),
                          st.text(st.characters(min_codepoint=1, max_codepoint=0x7f),
                                  max_size=40),
                          st.booleans()), max_size=30))
def test_a_capture_reads_as_json_reads_its_lines(
        records: list[tuple[float, str, str, bool]]) -> None:
    """The reader's short path for the lines ``frame`` writes gives the records ``json``
    gives, for any times, directions and frames (quotes, backslashes, controls: the long path)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "c.jsonl"
        cap = CaptureWriter(path, 0.0)
        t_s = 0.0
        for dt_s, direction, frame, plain in records:
            t_s += dt_s / 1e3
            if plain and frame.isprintable() and '"' not in frame and "\\" not in frame:
                cap.frame(t_s, "in" if direction == "in" else "out", frame)
            else:
                cap.write(t_s, "in" if direction == "in" else "out", frame, None)
        cap.close()
        by_json = [CaptureRecord(float(o["t_s"]), o["dir"], o["frame"], o["error"])
                   for o in map(json.loads, path.read_text().splitlines())]
        assert list(read_capture(path)) == by_json
