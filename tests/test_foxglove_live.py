"""Live view: ``armbench emulate --foxglove`` and ``armbench monitor --foxglove`` serve the joint
stream over the Foxglove WebSocket protocol; a client of its own (``websockets``, speaking
``foxglove.sdk.v1``) subscribes and gets JointState and TF messages at the arm's reply rate,
decoded by an independent ROS 2 decoder (``rosbags``). Real processes, real sockets."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import re
import struct
import subprocess
import sys
import time
from collections import Counter
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import IO, Any

import pytest
import websockets
from rosbags.typesys import Stores, get_typestore

from armbench.drivers.model.errors import ArmbenchError
from armbench.frontends.foxglove.live import parse_endpoint

ROOT = Path(__file__).resolve().parents[1]
TOPICS = ("/joint_states", "/joint_states/true", "/tf", "/robot_description")


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT),
                                                         os.environ.get("PYTHONPATH", "")]))


@contextlib.contextmanager
def _process(*args: str, stdout: int | IO[str] = subprocess.PIPE
             ) -> Iterator[subprocess.Popen[str]]:
    proc = subprocess.Popen([sys.executable, "-m", "armbench", *args], env=_env(),
                            stdout=stdout, stderr=subprocess.PIPE, text=True)
    try:
        yield proc
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _wait_line(stream: Any, pattern: str, timeout_s: float = 60.0) -> re.Match[str]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = stream.readline()
        if not line:
            break
        m = re.search(pattern, line)
        if m:
            return m
    raise AssertionError(f"no line matching {pattern!r}")


class _Client:
    """A Foxglove WebSocket client: advertised channels, subscriptions, received messages."""

    def __init__(self, ws: Any) -> None:
        self.ws = ws
        self.channels: dict[str, dict[str, Any]] = {}
        self.by_sub: dict[int, str] = {}

    async def advertised(self, topics: tuple[str, ...], timeout_s: float = 10.0) -> None:
        async with asyncio.timeout(timeout_s):
            while not all(t in self.channels for t in topics):
                msg = await self.ws.recv()
                if isinstance(msg, str):
                    obj = json.loads(msg)
                    if obj.get("op") == "advertise":
                        for ch in obj["channels"]:
                            self.channels[ch["topic"]] = ch

    async def subscribe(self, topics: tuple[str, ...]) -> None:
        subs = []
        for k, topic in enumerate(topics, 1):
            self.by_sub[k] = topic
            subs.append({"id": k, "channelId": self.channels[topic]["id"]})
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def collect(self, seconds: float) -> list[tuple[str, int, bytes]]:
        out: list[tuple[str, int, bytes]] = []
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            try:
                msg = await asyncio.wait_for(self.ws.recv(), left)
            except TimeoutError:
                break
            if isinstance(msg, bytes) and msg[0] == 1:  # MessageData
                sub, t_ns = struct.unpack_from("<IQ", msg, 1)
                out.append((self.by_sub[sub], t_ns, msg[13:]))
        return out


@contextlib.asynccontextmanager
async def _connect(port: int) -> AsyncIterator[_Client]:
    async with websockets.connect(f"ws://127.0.0.1:{port}",
                                  subprotocols=["foxglove.sdk.v1"]) as ws:  # type: ignore[list-item]
        yield _Client(ws)


def _check_messages(client: _Client, got: list[tuple[str, int, bytes]]) -> Counter[str]:
    store = get_typestore(Stores.ROS2_HUMBLE)
    for topic in ("/joint_states", "/tf"):
        ch = client.channels[topic]
        assert ch["encoding"] == "cdr" and ch["schemaEncoding"] == "ros2msg"
    counts = Counter(topic for topic, _, _ in got)
    for topic, _, data in got[:200]:
        name = client.channels[topic]["schemaName"]
        msg: Any = store.deserialize_cdr(data, name)
        if topic.startswith("/joint_states"):
            assert list(msg.name) == ["j1", "j2", "j3", "j4"] and len(msg.position) == 4
        elif topic == "/tf":
            assert [t.child_frame_id for t in msg.transforms] == [
                f"link{i}_root" for i in range(1, 5)]
    return counts


async def _count_replies(reader: asyncio.StreamReader, seconds: float) -> int:
    n = 0
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        try:
            data = await asyncio.wait_for(reader.read(4096), left)
        except TimeoutError:
            break
        n += data.count(b"#")
    return n


def test_emulate_serves_the_joint_stream_at_the_reply_rate() -> None:
    with _process("emulate", "--tcp", "127.0.0.1:0", "--foxglove", "127.0.0.1:0") as proc:
        fox = int(_wait_line(proc.stdout, r"Foxglove live view on ws://127\.0\.0\.1:(\d+)")[1])
        arm = int(_wait_line(proc.stdout, r"serving the arm on socket://127\.0\.0\.1:(\d+)")[1])

        async def main() -> tuple[Counter[str], int, list[tuple[str, int, bytes]]]:
            reader, writer = await asyncio.open_connection("127.0.0.1", arm)
            try:
                async with _connect(fox) as client:
                    await client.advertised(TOPICS)
                    await client.subscribe(("/joint_states", "/joint_states/true", "/tf"))
                    await _count_replies(reader, 0.5)  # both streams flowing
                    got, replies = await asyncio.gather(client.collect(3.0),
                                                        _count_replies(reader, 3.0))
                    return _check_messages(client, got), replies, got
            finally:
                writer.close()

        counts, replies, got = asyncio.run(main())
    # ~410 replies per second on the arm's own socket, fewer from an emulator starved of CPU
    # (it drops the loops it cannot catch up): the stream flows, and the live view keeps pace
    assert replies > 100
    for topic in ("/joint_states", "/joint_states/true", "/tf"):
        times = [t for name, t, _ in got if name == topic]
        rate = (len(times) - 1) / ((times[-1] - times[0]) / 1e9)  # by the messages' own clock
        # both counted by clients on a shared machine: a quarter's tolerance
        assert 0.75 * replies / 3.0 <= rate <= 1.25 * replies / 3.0, (topic, rate, replies)
    # one /tf per reported state: the 3 s window may close between a state and its /tf
    assert abs(counts["/joint_states"] - counts["/tf"]) <= 1


def test_monitor_serves_the_joint_stream_at_the_reply_rate(tmp_path: Path) -> None:
    """Every state the monitor received (its ``--json`` lines) while a client listened is on
    ``/joint_states``, stamped with the reply's time: the live view runs at the arm's reply rate
    whatever rate a busy machine lets the arm reach."""
    received = tmp_path / "states.jsonl"
    with _process("emulate", "--tcp", "127.0.0.1:0") as emu, received.open("w") as out:
        arm = int(_wait_line(emu.stdout, r"serving the arm on socket://127\.0\.0\.1:(\d+)")[1])
        with _process("monitor", "--port", f"socket://127.0.0.1:{arm}", "--json",
                      "--reply-timeout", "5", "--foxglove", "127.0.0.1:0", stdout=out) as mon:
            fox = int(_wait_line(mon.stderr, r"Foxglove live view on ws://127\.0\.0\.1:(\d+)")[1])

            async def main() -> tuple[Counter[str], list[tuple[str, int, bytes]]]:
                async with _connect(fox) as client:
                    await client.advertised(TOPICS)
                    await client.subscribe(("/joint_states", "/tf"))
                    got = await client.collect(2.5)
                async with _connect(fox) as client:  # alone: not lost among 800 states a second
                    await client.advertised(TOPICS)
                    await client.subscribe(("/robot_description",))
                    got += await client.collect(2.5)
                return _check_messages(client, got), got

            counts, got = asyncio.run(main())
    states = [t for topic, t, _ in got if topic == "/joint_states"]
    replies = [round(json.loads(line)["t_s"] * 1e9) for line in received.read_text().splitlines()]
    # the replies the monitor took while the first client listened
    between = [t for t in replies if states[0] <= t <= states[-1]]
    # each message is a reply, in order; the server may drop a few for a client it finds slow
    assert set(states) <= set(between) and states == sorted(states)
    assert len(states) >= 0.9 * len(between), (len(states), len(between))
    rate = (len(states) - 1) / ((states[-1] - states[0]) / 1e9)
    assert rate < 500, rate  # never more than the arm's ~410 replies per second
    assert counts["/tf"] >= 0.9 * counts["/joint_states"]
    assert counts["/robot_description"] >= 1  # sent again every second


def test_endpoint_parsing() -> None:
    assert parse_endpoint("8765") == ("127.0.0.1", 8765)
    assert parse_endpoint(":9000") == ("127.0.0.1", 9000)
    assert parse_endpoint("0.0.0.0:9000") == ("0.0.0.0", 9000)
    assert parse_endpoint("[::1]:9000") == ("::1", 9000)
    for bad in ("host:", "host:x", "1:70000"):
        with pytest.raises(ArmbenchError, match="--foxglove"):
            parse_endpoint(bad)
