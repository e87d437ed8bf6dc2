"""``capture.mcap``: a run's capture read back with the ``mcap`` library's own reader and every
message decoded by an independent ROS 2 decoder (``rosbags``), checked against the run's record
and the emulators' counters; the same records from MCAP and JSON Lines; a run killed mid-way."""

from __future__ import annotations

import dataclasses
import datetime
import io
import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import zstandard
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from armbench.bench.runner import EXIT_PASS, RunOptions, run_sync
from armbench.drivers.capture.jsonl import CaptureWriter
from armbench.drivers.capture.mcap_writer import McapCapture
from armbench.drivers.capture.part import PartWriter
from armbench.drivers.capture.read import (
    capture_lines,
    capture_start_ns,
    is_mcap,
    open_capture,
    read_attachment,
    read_joint_states,
    read_tally,
    replay_capture,
)
from armbench.drivers.capture.tally import TALLY_KEY
from armbench.drivers.model import ros2
from armbench.drivers.model.kinematics import fk
from armbench.drivers.model.protocol import AngleDecoder, Reply
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.urdf import robot_urdf
from armbench.record import RunRecord, load_record
from armbench.reports.render.capture_summary import summarize_capture

TOPICS = {"/uart/tx", "/uart/rx", "/joint_states", "/joint_states/true", "/joint_states_goal",
          "/tf", "/tf_static", "/robot_description", "/bench/events"}

CONFIG = """spec_version = "armbench-limits/1"

[suites.accuracy]
laps = 1
styles = ["coordinated"]
side_m = 0.04

[suites.startup-recovery]
trials = 2
conditions = ["cw-away-near"]
joint_sets = [[2, 3, 4]]
wear_duration_s = 0.0
"""


class _Emulators(list[Any]):
    """Emulator factory keeping every emulator, for their counters."""

    def __call__(self, robot: Any, settings: Any, faults: Any) -> Any:
        from armbench.fakes.firmware.arm_emulator import ArmEmulator

        emulator = ArmEmulator(robot, settings, faults)
        self.append(emulator)
        return emulator


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, _Emulators]:
    root = tmp_path_factory.mktemp("mcap")
    (root / "bench.toml").write_text(CONFIG)
    emulators = _Emulators()
    outcome = run_sync(RunOptions(suites=["accuracy", "startup-recovery"],
                                  config=root / "bench.toml", out=root / "run", seed=5),
                       progress=io.StringIO(), emulator_factory=emulators)
    assert outcome.exit_status == EXIT_PASS, outcome.error
    return root / "run", emulators


def _typestore(schemas: dict[str, str]) -> Any:
    store = get_typestore(Stores.ROS2_HUMBLE)
    for name, text in schemas.items():
        if name.startswith("armbench_msgs/"):
            store.register(get_types_from_msg(text.split("=" * 80)[0], name))
    return store


def _read_all(path: Path) -> tuple[dict[str, list[tuple[int, Any]]], Any]:
    """Every message per topic as (log time, rosbags-decoded message), with the summary."""
    out: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    with path.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        schemas = {s.name: s.data.decode() for s in summary.schemas.values()}
        assert all(s.encoding == "ros2msg" for s in summary.schemas.values())
        assert all(c.message_encoding == "cdr" for c in summary.channels.values())
        store = _typestore(schemas)
        for schema, channel, message in reader.iter_messages():
            assert schema is not None
            assert message.publish_time == message.log_time
            out[channel.topic].append((message.log_time,
                                       store.deserialize_cdr(message.data, schema.name)))
    return out, summary


def _stamp(msg: Any) -> int:
    stamp = msg.header.stamp if hasattr(msg, "header") else msg.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def test_every_channel_decodes_and_matches_the_record(run_dir: tuple[Path, _Emulators]) -> None:
    out, emulators = run_dir
    path = out / "capture.mcap"
    assert is_mcap(path) and not list(out.glob(".capture*"))
    record: RunRecord = load_record(out / "results.json")
    settings = RobotSettings.from_mapping(record.environment.settings)
    messages, summary = _read_all(path)
    assert set(messages) == TOPICS
    # times are the wall clock: the run's start (its record's creation, to the microsecond)
    # plus the run clock, and the start is stored in the file
    start_ns = capture_start_ns(path)
    created = datetime.datetime.fromisoformat(record.created)
    assert abs(start_ns - created.timestamp() * 1e9) < 1e3
    assert datetime.datetime.fromtimestamp(
        min(t for items in messages.values() for t, _ in items) / 1e9, datetime.UTC
    ).date() == created.date()
    counts = Counter({summary.channels[c].topic: n
                      for c, n in summary.statistics.channel_message_counts.items()})
    assert counts == Counter({t: len(m) for t, m in messages.items()})
    for topic, items in messages.items():  # every stamp is the message's log time
        if topic not in ("/robot_description", "/tf", "/tf_static"):
            assert all(_stamp(m) == t for t, m in items), topic

    # Raw frames: every command the emulators received, every reply they delivered.
    frames: dict[str, list[tuple[int, str]]] = {"/uart/rx": [], "/uart/tx": []}
    for topic, table in frames.items():
        for _, m in messages[topic]:
            assert len(m.offset_ns) == len(m.frame) == len(m.error)
            for off, frame, error in zip(m.offset_ns, m.frame, m.error, strict=True):
                assert error == ""
                table.append((_stamp(m) + int(off), frame))
    commands = sum(e.stats().commands for e in emulators)
    # replies printed, less those a power cut lost on the line and one per connection at most
    # still on the line when it closed
    replies = sum((e.uart.tx_bytes - e.uart.tx_dropped_bytes) // 25 for e in emulators)
    assert sum(len(m.frame) for _, m in messages["/uart/tx"]) == commands > 0
    received = sum(len(m.frame) for _, m in messages["/uart/rx"])
    assert replies - len(emulators) <= received <= replies and received > 1000, (
        received, replies, len(emulators))

    # Goals: one per command, positions and duty (effort) as in the frame.
    decode = AngleDecoder(settings.lower_rad, settings.upper_rad)
    assert len(messages["/joint_states_goal"]) == commands
    for (t, m), (t_tx, frame) in zip(messages["/joint_states_goal"], frames["/uart/tx"],
                                     strict=True):
        assert t == t_tx
        values = [int(v) for v in frame[1:-1].split(",")]
        assert list(m.name) == ["j1", "j2", "j3", "j4"]
        assert list(m.position) == list(decode(Reply(*values[0::2])))
        assert list(m.effort) == [float(d) for d in values[1::2]]

    # Reported states: each one is the reply received at its time, decoded; /tf beside it.
    states = messages["/joint_states"]
    replies_at = dict(frames["/uart/rx"])  # a state is the first reply of its time
    assert len(states) == len(messages["/tf"]) > 50
    statics = {tr.child_frame_id: tr for tr in messages["/tf_static"][0][1].transforms}
    for (t, m), (t_tf, tf) in zip(states, messages["/tf"], strict=True):
        assert t == t_tf
        assert tuple(m.position) == decode(Reply(*map(int, replies_at[t][1:-1].split(","))))
        pose = np.eye(4)
        for tr in tf.transforms:
            assert _stamp(tr) == t
            fixed = statics[tr.child_frame_id.replace("_root", "")]
            pose = pose @ _matrix(tr.transform) @ _matrix(fixed.transform)
        assert np.abs(pose - fk(np.array(m.position), settings)).max() < 1e-9

    # Truth: the emulator's; during the accuracy trials close to what the firmware reported
    # (encoder and backlash apart; start-up recovery's cold boots report 0 wherever the arm is).
    truth = messages["/joint_states/true"]
    assert len(truth) > 50
    spans = [(start_ns + round(t.started_s * 1e9), start_ns + round(t.ended_s * 1e9))
             for t in record.suites["accuracy"].trials]
    reported = np.array([t for t, _ in states])
    near = 0
    for t, m in truth:
        k = int(np.searchsorted(reported, t))
        if (k < len(states) and states[k][0] - t < 5_000_000
                and any(a <= t <= b for a, b in spans)):
            near += 1
            assert np.abs(np.array(m.position) - np.array(states[k][1].position)).max() < 0.01
    assert near >= 5

    # Events: the record's trials, and the power switches of start-up recovery.
    events = [(t, m) for t, m in messages["/bench/events"]]
    trials = [(name, tr) for name, s in record.suites.items()
              for tr in (*s.trials, *s.superseded_trials)]
    starts = {(m.suite, m.trial): t for t, m in events if m.kind == "trial_start"}
    ends = {(m.suite, m.trial): (t, json.loads(m.detail)) for t, m in events
            if m.kind == "trial_end"}
    assert len(starts) == len(ends) == len(trials)
    for name, tr in trials:
        assert starts[(name, tr.index)] == start_ns + round(tr.started_s * 1e9)
        assert ends[(name, tr.index)][0] == start_ns + round(tr.ended_s * 1e9)
        assert ends[(name, tr.index)][1]["status"] == tr.status
    kinds = Counter(m.kind for _, m in events)
    assert kinds["power_off"] >= 2 and kinds["power_on"] >= 2

    # Once: the URDF and the fixed link frames; the metadata and the attachments.
    assert messages["/robot_description"][0][1].data == robot_urdf(settings)
    with path.open("rb") as fh:
        reader = make_reader(fh)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        attached = {a.name: a.data for a in reader.iter_attachments()}
    assert meta["armbench"]["run_id"] == record.run_id
    assert meta["armbench"]["start_ns"] == str(start_ns)
    assert meta["armbench"]["seed"] == "5"
    assert RobotSettings.from_mapping(json.loads(meta["armbench"]["settings"])) == settings
    assert zstandard.ZstdDecompressor().decompressobj().decompress(
        attached["results.json.zst"]) == (out / "results.json").read_bytes()


def _matrix(transform: Any) -> Any:
    x, y, z, w = (transform.rotation.x, transform.rotation.y, transform.rotation.z,
                  transform.rotation.w)
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = [transform.translation.x, transform.translation.y, transform.translation.z]
    return m


def test_reader_gives_the_records_of_the_run(run_dir: tuple[Path, _Emulators]) -> None:
    out, _ = run_dir
    records = list(open_capture(out / "capture.mcap"))
    times = [r.t_s for r in records]
    assert times == sorted(times) and {r.dir for r in records} == {"in", "out"}
    # on the run clock, as the record's times: the file's wall-clock start taken off
    end_s = load_record(out / "results.json").end_s
    assert times[0] >= 0.0 and times[-1] <= end_s + 1e-6, (times[0], times[-1], end_s)
    truth = read_joint_states(out / "capture.mcap")
    assert truth and truth[0][0] >= 0.0 and truth[-1][0] <= end_s + 1e-6
    assert list(open_capture(out / "capture.mcap")) == records
    summary = summarize_capture(out / "capture.mcap")
    assert summary.records == len(records) and summary.bad_lines == 0
    assert summary.frames_out == sum(r.dir == "out" for r in records)
    # the tally stored while the run wrote the capture is what reading it back gives
    _same_summaries(summary, summarize_capture(out / "capture.mcap", stored=False))


def _same_summaries(x: Any, y: Any) -> None:
    for field in dataclasses.fields(x):
        if field.name not in ("path", "size_bytes"):
            u, v = getattr(x, field.name), getattr(y, field.name)
            assert np.array_equal(u, v) if isinstance(u, np.ndarray) else u == v, field.name


def _capture(w: CaptureWriter) -> None:
    t = 10.0
    for k in range(500):
        t += 0.0024
        w.frame(t, "out" if k % 9 == 0 else "in", f"${k:05d},00010,00020,00030#"
                if k % 9 else "$00100,50,00200,60,00300,70,00400,80#")
        if k % 97 == 0:
            w.write(t + 1e-4, "in", "$0x\\xff\"q", "bytes outside a frame")
    w.close()


def test_mcap_and_jsonl_give_the_same_records(tmp_path: Path) -> None:
    """The same frames through the JSON Lines writer and through a capture part into MCAP."""
    jsonl = tmp_path / "capture.jsonl"
    _capture(CaptureWriter(jsonl, 10.0, batch_records=7))
    _capture(PartWriter(tmp_path / "x.part", 10.0, batch_records=7))
    capture = McapCapture(tmp_path / "capture.mcap", RobotSettings())
    assert capture.add_part(tmp_path / "x.part") == 506
    capture.close()
    a = list(open_capture(jsonl))
    b = list(open_capture(tmp_path / "capture.mcap"))
    assert sorted(a) == sorted(b) and len(a) == 500 + 6
    x, y = (summarize_capture(p) for p in (jsonl, tmp_path / "capture.mcap"))
    assert x.errors_in == 6 and x.resyncs == 6
    _same_summaries(x, y)  # y: the tally the MCAP writer stored
    _same_summaries(x, summarize_capture(tmp_path / "capture.mcap", stored=False))
    with capture_lines(tmp_path / "capture.mcap") as lines:
        assert sum(1 for _ in lines) == len(a)
    assert [c.command for c in replay_capture(tmp_path / "capture.mcap")] == [
        c.command for c in replay_capture(jsonl)]


def test_a_damaged_stored_tally_is_counted_again(tmp_path: Path) -> None:
    """The stored tally is a metadata entry (no checksum of its own): with a digit of it
    flipped, its check says so and the summary counts the records instead."""
    _capture(PartWriter(tmp_path / "x.part", 10.0, batch_records=7))
    capture = McapCapture(tmp_path / "capture.mcap", RobotSettings())
    capture.add_part(tmp_path / "x.part")
    capture.close()
    path = tmp_path / "capture.mcap"
    data = bytearray(path.read_bytes())
    key = len(TALLY_KEY).to_bytes(4, "little") + TALLY_KEY.encode()
    value = data.index(key) + len(key) + 4
    digit = value + next(k for k, c in enumerate(data[value:]) if chr(c).isdigit())
    data[digit] ^= 0x01
    path.write_bytes(data)
    assert read_tally(path) is None
    _same_summaries(summarize_capture(path), summarize_capture(path, stored=False))


def test_a_run_killed_mid_way_leaves_a_readable_capture(tmp_path: Path) -> None:
    """A real ``armbench run`` process killed (SIGKILL) once its capture holds a chunk: the
    file has no summary, and the readers give every frame up to the last complete chunk."""
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(Path(__file__).resolve().parents[1]), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen([sys.executable, "-m", "armbench", "run", "repeatability",
                             "--out", str(out), "--workers", "1"], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None:
            path = out / "capture.mcap"
            if path.exists() and path.stat().st_size > 200_000:
                break
            time.sleep(0.2)
        assert proc.poll() is None, "the run ended before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    data = (out / "capture.mcap").read_bytes()
    assert not data.endswith(b"\x89MCAP0\r\n")  # no footer: cut short
    records = list(open_capture(out / "capture.mcap"))
    assert len(records) > 1000
    times = [r.t_s for r in records]
    assert times == sorted(times)
    assert all(r.error is None and r.frame.startswith("$") for r in records)
    assert summarize_capture(out / "capture.mcap").records == len(records)


@given(st.integers(0, 2**31 * 10**9 - 1),
       st.lists(st.floats(allow_nan=False), min_size=28, max_size=28),
       st.lists(st.text(max_size=40), min_size=0, max_size=6))
@settings(max_examples=60, deadline=None)
def test_fast_encoders_are_byte_for_byte_mcap_ros2s(t_ns: int, values: list[float],
                                                     texts: list[str]) -> None:
    """The fixed-layout encoders give exactly what ``mcap-ros2-support``'s serializer gives."""
    sec, nsec = divmod(t_ns, 1_000_000_000)
    stamp = {"sec": sec, "nanosec": nsec}
    names = ["j1", "j2", "j3", "j4"]
    js = ros2.dynamic_encoder(ros2.JOINT_STATE)
    assert ros2.JointStateEncoder().encode(t_ns, values[:4]) == js(
        {"header": {"stamp": stamp, "frame_id": ""}, "name": names, "position": values[:4],
         "velocity": [], "effort": []})
    assert ros2.JointStateEncoder(with_effort=True).encode(t_ns, values[:4], values[4:8]) == js(
        {"header": {"stamp": stamp, "frame_id": ""}, "name": names, "position": values[:4],
         "velocity": [], "effort": values[4:8]})
    poses = [tuple(values[7 * k:7 * k + 7]) for k in range(4)]
    assert ros2.TfEncoder(ros2.MOVING_PAIRS).encode(t_ns, poses) == ros2.dynamic_encoder(
        ros2.TF_MESSAGE)({"transforms": [
            {"header": {"stamp": stamp, "frame_id": parent}, "child_frame_id": child,
             "transform": {"translation": dict(zip("xyz", p[:3], strict=True)),
                           "rotation": dict(zip("xyzw", p[3:], strict=True))}}
            for (parent, child), p in zip(ros2.MOVING_PAIRS, poses, strict=True)]})
    rows = np.array([t_ns, t_ns // 3], dtype=np.int64)
    q = np.array([values[:4], values[4:8]], dtype=np.float64)
    assert ros2.JointStateEncoder().encode_many(rows, q) == [
        ros2.JointStateEncoder().encode(int(t), list(v)) for t, v in zip(rows, q, strict=True)]
    tf = ros2.TfEncoder(ros2.MOVING_PAIRS)
    assert tf.encode_many(rows, np.array([poses, poses[::-1]])) == [
        tf.encode(int(rows[0]), poses), tf.encode(int(rows[1]), poses[::-1])]
    offsets = list(range(len(texts)))
    errors = texts[::-1]
    frames = ros2.dynamic_encoder(ros2.UART_FRAMES)(
        {"stamp": stamp, "offset_ns": offsets, "frame": texts, "error": errors})
    assert ros2.encode_uart_frames(t_ns, offsets, texts, errors) == frames
    if all(len(x) == len(texts[0]) and x.isascii() and "\x00" not in x for x in texts):
        assert ros2.encode_uart_frames_bytes(t_ns, np.array(offsets, dtype=np.int64),
                                             [x.encode() for x in texts]) == \
            ros2.dynamic_encoder(ros2.UART_FRAMES)(
                {"stamp": stamp, "offset_ns": offsets, "frame": texts,
                 "error": [""] * len(texts)})


def test_the_report_joins_the_finished_capture(run_dir: tuple[Path, _Emulators],
                                               tmp_path: Path) -> None:
    """``write_reports`` attaches ``report.html`` to ``capture.mcap`` after the capture was
    closed: the summary then indexes it beside ``results.json`` (a valid file, CRCs checked),
    every message is still there; within a size bound that has no room for it, the capture is
    left as it was."""
    from mcap.stream_reader import StreamReader

    from armbench.cli.commands.run_files import write_reports

    out, _ = run_dir
    for bound, name in ((None, "free"), (1, "bounded")):
        here = tmp_path / name
        here.mkdir()
        for file in ("results.json", "capture.mcap"):
            (here / file).write_bytes((out / file).read_bytes())
        before = (here / "capture.mcap").read_bytes()
        write_reports(load_record(here / "results.json"), here, capture_max_bytes=bound)
        path = here / "capture.mcap"
        if bound is not None:
            assert path.read_bytes() == before
            continue
        with path.open("rb") as fh:
            reader = make_reader(fh)
            summary = reader.get_summary()
            assert summary is not None and summary.statistics is not None
            assert summary.statistics.attachment_count == 2
            assert {i.name for i in summary.attachment_indexes} == {"results.json.zst",
                                                                      "report.html.zst"}
            # both at the run's start on the wall clock, as the messages' times count from it
            start_ns = capture_start_ns(path)
            assert start_ns > 0
            assert {i.log_time for i in summary.attachment_indexes} == {start_ns}
            assert read_attachment(path, "report.html") == (here / "report.html").read_bytes()
            assert sum(1 for _ in reader.iter_messages()) == summary.statistics.message_count
        with path.open("rb") as fh:
            assert sum(1 for _ in StreamReader(fh, validate_crcs=True).records) > 0


def test_a_capture_without_summary_gets_no_attachment(run_dir: tuple[Path, _Emulators],
                                                      tmp_path: Path) -> None:
    """A killed run's capture (cut before its summary) or a file that is not MCAP is left as it
    was: ``append_attachment`` reads only the file's head and tail and says False."""
    from armbench.drivers.capture.append import append_attachment

    out, _ = run_dir
    whole = (out / "capture.mcap").read_bytes()
    for name, data in (("cut", whole[: len(whole) // 2]), ("text", b"not an mcap file" * 8),
                       ("empty", b"")):
        path = tmp_path / f"{name}.mcap"
        path.write_bytes(data)
        assert not append_attachment(path, "x.zst", b"data", "application/zstd"), name
        assert path.read_bytes() == data, name
