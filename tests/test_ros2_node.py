"""``armbench ros2`` with real rclpy and Fast DDS: the node in this process (or as the command), a
separate process as the ROS client (``armbench.frontends.ros2_node.client``).

Each test has a ROS domain of its own (``ROS_DOMAIN_ID``) and discovery on this host only, so
parallel runs do not hear each other. Waits are bounded by the client's own guard, not asserted
on: on virtual time the emulator runs as fast as the machine lets it.
"""

from __future__ import annotations

import asyncio
import json
import signal
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable
from typing import Any

import pytest
from netutil import free_port

from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.frontends.ros2_node import missing_ros2

pytestmark = [pytest.mark.skipif(missing_ros2() is not None,
                                 reason=f"armbench[ros2] not installed: {missing_ros2()}"),
              pytest.mark.usefixtures("ros_domain")]  # a domain of its own (conftest.py)

S = RobotSettings()
NAMES = [j.name for j in S.joints]
CLIENT = [sys.executable, "-m", "armbench.frontends.ros2_node.client"]
#: Real seconds a client or a command may take at most on a loaded machine (a hang guard).
GUARD_S = 90.0
#: Real seconds an ``idle`` subscriber stays at most: the test ends it (killed) when its run is
#: over, however long a loaded machine makes that; this only ends one the test left behind.
IDLE_GUARD_S = 1800.0


async def _client(*args: str) -> dict[str, Any]:
    proc = await asyncio.create_subprocess_exec(
        *CLIENT, *args, "--timeout", str(GUARD_S), stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE)
    out, err = await proc.communicate()
    assert proc.returncode == 0, (out.decode(), err.decode()[-2000:])
    result: dict[str, Any] = json.loads(out.decode().splitlines()[-1])
    return result


def _with_node(*client_args: str, port: str = "fake://",
               during: Callable[[Any], Awaitable[None]] | None = None,
               ) -> tuple[Any, Any, dict[str, Any], list[Any]]:
    """The node on ``port`` (virtual time, ``/clock``) while one client runs (and ``during(node)``
    beside it): the node, its arm, the client's result and every state the arm received."""
    from armbench.frontends.ros2_node.node import ArmNode, NodeOptions, PublishingArm

    async def main() -> tuple[Any, Any, dict[str, Any], list[Any]]:
        async with PublishingArm(port, S) as arm:
            node = ArmNode(arm, NodeOptions(clock=True))
            serving = asyncio.ensure_future(node.run())
            side = asyncio.ensure_future(during(node)) if during is not None else None
            try:
                with arm.record_states() as states:
                    result = await _client(*client_args)
            finally:
                for task in (serving, side):
                    if task is not None:
                        task.cancel()
                        await asyncio.wait({task})
            return node, arm, result, list(states)

    return run_virtual(main())


def test_joint_states_every_reply_with_clock_and_the_urdf_latched() -> None:
    node, _, got, states = _with_node("listen", "--count", "2000", "--sim-time")
    assert got["count"] >= 2000 and got["stamps_in_order"]  # more while the URDF comes
    # every reply in the window the subscriber saw (stamps are the virtual reply times)
    window = [s for s in states if got["first_stamp_s"] - 1e-9 <= s.t_s
              <= got["last_stamp_s"] + 1e-9]
    assert got["count"] / len(window) >= 0.95
    assert got["clocks"] > 0 and got["clock_last_s"] is not None
    # a use_sim_time node runs on the bench's virtual time (its own /clock subscription may be
    # a message or two ahead of the client's; ROS times are whole nanoseconds, rounded)
    assert got["first_stamp_s"] - 1e-9 <= got["node_now_s"] <= states[-1].t_s + 1e-9
    urdf = got["robot_description"]  # published before the client existed: transient local
    assert urdf.startswith("<?xml") and all(f'name="{n}"' in urdf for n in NAMES)
    assert node.published >= got["count"]


def test_a_trajectory_is_executed_with_coordinated_streaming() -> None:
    target = [0.2, -0.1, 0.15, 0.3]
    t = {"names": NAMES, "points": [[0.1, -0.05, 0.05, 0.1], target], "times_s": [2.0, 4.0]}
    node, arm, got, _ = _with_node("send", "--trajectory", json.dumps(t))
    assert got["state"] == "done", got
    tol = arm.default_tolerance_rad()
    assert all(abs(a - b) <= e for a, b, e in zip(got["q_rad"], target, tol, strict=True)), got
    run = node.last_run
    assert run is not None and len(run.waypoints) == 2
    # the goals as written, seen by the client in order
    assert got["seen"]["commanded"][-2:] == [list(w.q_rad) for w in run.waypoints]
    assert run.duration_s == pytest.approx(4.0, rel=0.1)  # time_from_start held by the duties


def test_an_invalid_trajectory_is_rejected_and_nothing_moves(
        caplog: pytest.LogCaptureFixture) -> None:
    upper = S.joints[1].upper_rad
    t = {"names": NAMES, "points": [[0.0, upper + 0.2, 0.0, 0.0]], "times_s": [5.0]}
    node, arm, got, _ = _with_node("send", "--trajectory", json.dumps(t), "--wait-event",
                                   "trajectory_rejected")
    assert got["state"] == "rejected" and NAMES[1] in got["reason"], got
    assert got["seen"]["events"] == ["trajectory_rejected"] and got["seen"]["commanded"] == []
    assert node.last_run is None
    assert arm.commands_sent == 1  # only the hold of the shutdown: nothing was streamed
    assert any("rejected, nothing moved" in r.getMessage() for r in caplog.records)


def test_a_new_trajectory_replaces_the_one_running() -> None:
    # ~200 simulated s (duty 1): still running when the next one comes, however slow the host
    slow = {"names": NAMES, "points": [[2.0, 0.0, 0.0, 0.0]], "times_s": [200.0]}
    target = [0.0, 0.1, 0.0, 0.0]
    fast = {"names": NAMES, "points": [target], "times_s": [10.0]}
    node, arm, got, _ = _with_node("send", "--trajectory", json.dumps(slow),
                                   "--trajectory", json.dumps(fast))
    first, second = got["statuses"]
    assert first["state"] == "preempted" and second["state"] == "done", got
    tol = arm.default_tolerance_rad()
    assert all(abs(a - b) <= e for a, b, e in zip(second["q_rad"], target, tol, strict=True))
    assert node.accepted == 2


def test_a_trajectory_cut_short_by_the_shutdown_is_aborted_not_preempted() -> None:
    """Shutdown is not a newer trajectory: the one running ends ``aborted``, reason
    ``shutdown`` (it was reported ``preempted``), and the client still gets it."""
    from armbench.frontends.ros2_node.node import ArmNode, NodeOptions, PublishingArm

    slow = {"names": NAMES, "points": [[2.0, 0.0, 0.0, 0.0]], "times_s": [200.0]}

    async def main() -> tuple[Any, dict[str, Any]]:
        async with PublishingArm("fake://", S) as arm:
            node = ArmNode(arm, NodeOptions(clock=True))
            serving = asyncio.ensure_future(node.run())
            client = asyncio.ensure_future(_client("send", "--trajectory", json.dumps(slow)))
            while node.accepted == 0:
                await asyncio.sleep(0.01)
            await asyncio.sleep(1.0)  # under way: ~200 simulated s to go
            serving.cancel()
            await asyncio.wait({serving})
            return node, await client

    node, got = run_virtual(main())
    assert (got["state"], got["reason"]) == ("aborted", "shutdown"), got
    assert node.finals == {"aborted": 1}


def test_a_huge_joint_name_is_echoed_shortened(tmp_path: Any,
                                               caplog: pytest.LogCaptureFixture) -> None:
    """A 10 MB joint name (through ROS, as a peer sends it) is refused, and the status, the
    event and the log line quote its first characters and its length, not the 10 MB."""
    path = tmp_path / "huge.json"
    path.write_text(json.dumps({"names": ["x" * 10_000_000, *NAMES[1:]],
                                "points": [[0.0] * 4], "times_s": [1.0]}))
    _, _, got, _ = _with_node("send", "--trajectory-file", str(path), "--wait-event",
                              "trajectory_rejected")
    assert got["state"] == "rejected" and "(10000000 characters)" in got["reason"], got
    assert len(got["reason"]) < 1000, len(got["reason"])
    rejected = [r.getMessage() for r in caplog.records if "rejected" in r.getMessage()]
    assert rejected and all(len(m) < 1000 for m in rejected), [len(m) for m in rejected]


def test_a_trajectory_of_too_many_points_is_refused_unread(
        caplog: pytest.LogCaptureFixture) -> None:
    from types import SimpleNamespace

    from armbench.frontends.ros2_node.node import MAX_POINTS, ArmNode, NodeOptions, PublishingArm

    point = SimpleNamespace(positions=[0.0] * 4, time_from_start=SimpleNamespace(sec=1, nanosec=0))
    msg = SimpleNamespace(joint_names=NAMES, points=[point] * (MAX_POINTS + 1),
                          header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=2)))

    async def main() -> tuple[Any, int]:
        async with PublishingArm("fake://", S) as arm:
            node = ArmNode(arm, NodeOptions(clock=True))
            serving = asyncio.ensure_future(node.run())
            node.intake.receive(msg, None)  # as the executor thread hands it over
            await asyncio.sleep(0.5)
            sent = arm.commands_sent
            serving.cancel()
            await asyncio.wait({serving})
            return node, sent

    node, sent = run_virtual(main())
    assert node.accepted == 0 and sent == 0
    assert any(f"more than the {MAX_POINTS} accepted" in r.getMessage() for r in caplog.records)


def test_a_realtime_factor_holds_virtual_time_back() -> None:
    import time

    from armbench.frontends.ros2_node.node import ArmNode, NodeOptions, PublishingArm

    async def main() -> float:
        async with PublishingArm("fake://", S) as arm:
            node = ArmNode(arm, NodeOptions(clock=True, realtime_factor=5.0))
            t0 = time.perf_counter()
            assert await node.run(5.0) == 0
            return time.perf_counter() - t0

    # 5 simulated s at most 5 times as fast as real time: at least ~1 real s (unpaced, a fraction
    # of that; a loaded machine only makes it longer)
    assert run_virtual(main()) >= 0.95


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


@pytest.mark.parametrize("mode", ["pace", "drop"])
def test_a_subscriber_that_never_reads_does_not_fill_or_stop_the_node(mode: str) -> None:
    """A reliable KEEP_ALL subscriber that takes nothing stops acknowledging once its own history
    is full; the node's /joint_states history is bounded, so the node serves on (every reply
    published or counted as dropped), its memory stays flat, and ``pace`` stops waiting for it."""
    from armbench.frontends.ros2_node.node import ArmNode, NodeOptions, PublishingArm

    duration_s = 150.0  # ~60 000 replies: several times what the subscriber's history holds

    async def main() -> tuple[Any, int, int, float]:
        async with PublishingArm("fake://", S) as arm:
            node = ArmNode(arm, NodeOptions(clock=True, slow_subscriber=mode,
                                            pace_timeout_s=1.0))
            idle = await asyncio.create_subprocess_exec(
                *CLIENT, "idle", "--timeout", str(IDLE_GUARD_S), stdout=asyncio.subprocess.PIPE)
            try:
                assert idle.stdout is not None
                assert b"subscribed" in await idle.stdout.readline()  # matched before we run
                rss0, seq0 = _rss_mb(), arm.state.seq
                status = await node.run(duration_s)
                grown, replies = _rss_mb() - rss0, arm.state.seq - seq0
                assert idle.returncode is None  # the subscriber was there all the run
            finally:
                if idle.returncode is None:
                    idle.kill()
                await idle.wait()
            return node, status, replies, grown

    node, status, replies, grown_mb = run_virtual(main())
    assert status == 0  # before: the node's publish failed (RCLError) and the node stopped
    # every reply while serving (the replies to the hold of the shutdown come after)
    assert node.published + node.dropped >= 0.99 * replies > 0
    assert node.dropped <= node.published / 10, (node.dropped, node.published)
    assert grown_mb < 30, grown_mb  # the history's bound, not the stream's length
    if mode == "drop":
        assert node.paced_s == 0.0 and node.stalls == 0


def test_nodes_in_namespaces_of_their_own_do_not_hear_each_other() -> None:
    """Two arms on one ROS domain (or two bench trials measured at once): a trajectory sent to
    one namespace moves that arm only."""
    from armbench.frontends.ros2_node.node import ArmNode, NodeOptions, PublishingArm

    target = [0.1, 0.0, 0.0, 0.0]
    t = {"names": NAMES, "points": [target], "times_s": [3.0]}

    async def main() -> tuple[dict[str, Any], list[int], list[int]]:
        async with PublishingArm("fake://", S) as arm_a, PublishingArm("fake://", S) as arm_b:
            nodes = [ArmNode(arm_a, NodeOptions(namespace="/arm_a", clock=True)),
                     ArmNode(arm_b, NodeOptions(namespace="/arm_b"))]
            serving = [asyncio.ensure_future(n.run()) for n in nodes]
            try:
                got = await _client("send", "--namespace", "/arm_a", "--trajectory",
                                    json.dumps(t))
            finally:
                for task in serving:
                    task.cancel()
                await asyncio.wait(serving)
            return got, [n.accepted for n in nodes], [a.commands_sent for a in (arm_a, arm_b)]

    got, accepted, sent = run_virtual(main())
    assert got["state"] == "done" and got["seen"]["commanded"], got
    assert accepted == [1, 0]
    assert sent[1] == 1  # arm b: only the hold of its node's shutdown


def test_an_empty_trajectory_stops_the_arm() -> None:
    _, arm, got, _ = _with_node("send", "--trajectory",
                                json.dumps({"names": NAMES, "points": [], "times_s": []}))
    assert got["state"] == "stopped" and len(got["q_rad"]) == 4
    assert arm.commands_sent == 2  # the hold it asked for, and the one of the shutdown


def test_a_silent_arm_aborts_the_trajectory_and_is_held(
        caplog: pytest.LogCaptureFixture) -> None:
    async def power_cut(node: Any) -> None:
        arm = node.arm
        while node.accepted == 0:
            await asyncio.sleep(0.01)
        await asyncio.sleep(1.0)  # under way
        holds = arm.commands_sent
        arm.emulator.power_off()
        while arm.commands_sent == holds:  # the node holds the arm
            await asyncio.sleep(0.01)
        arm.emulator.power_on()

    t = {"names": NAMES, "points": [[0.3, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]],
         "times_s": [10.0, 20.0]}
    node, _, got, _ = _with_node("send", "--trajectory", json.dumps(t), "--wait-event",
                                 "link_silent", during=power_cut)
    assert got["state"] == "aborted" and "fell silent" in got["reason"], got
    assert "link_silent" in got["seen"]["events"]
    assert node.last_run is None
    messages = [r.getMessage() for r in caplog.records]
    assert any("abandoning the trajectory and holding the arm" in m for m in messages)


def _start(argv: list[str], ready: str) -> tuple[subprocess.Popen[str], list[str]]:
    """Start ``argv``; return it once a line of its stderr or stdout holds ``ready``."""
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert proc.stdout is not None
    lines: list[str] = []
    for line in proc.stdout:
        lines.append(line)
        if ready in line:
            return proc, lines
    raise AssertionError(f"{argv} ended before saying {ready!r}: {''.join(lines)}")


def test_the_command_stops_the_arm_on_sigterm_and_says_so() -> None:
    proc, _ = _start([sys.executable, "-m", "armbench", "-v", "ros2", "--port", "fake://"],
                     "ROS 2 node 'armbench' serving")
    proc.send_signal(signal.SIGTERM)
    out, _ = proc.communicate(timeout=GUARD_S)
    assert proc.returncode == 0, out
    assert "node shut down: stopped the arm" in out


def test_the_command_hears_sigterm_while_it_holds_virtual_time_back() -> None:
    """``--realtime-factor 0.001``: a reply of the arm every ~2.4 real s. The hold was a blocking
    sleep per reply, and the loop saw the signal only after hundreds of them (at 1e-5: ~240 s a
    reply); now SIGTERM ends it at once, the arm stopped, exit 0."""
    proc, _ = _start([sys.executable, "-m", "armbench", "-v", "ros2", "--port", "fake://",
                      "--realtime-factor", "0.001"], "ROS 2 node 'armbench' serving")
    try:
        time.sleep(3.0)  # holding
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, out
    assert "node shut down: stopped the arm" in out


def test_ctrl_c_stops_the_arm_and_exits_130() -> None:
    """SIGINT is an interruption (exit 130, as everywhere in armbench); SIGTERM, the way a
    service is stopped, a clean 0 (above). The arm is stopped either way."""
    proc, _ = _start([sys.executable, "-m", "armbench", "-v", "ros2", "--port", "fake://"],
                     "ROS 2 node 'armbench' serving")
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=GUARD_S)
    assert proc.returncode == 130, out
    assert "node shut down: stopped the arm" in out and "Traceback" not in out


def test_the_command_says_the_link_is_lost_and_exits_1() -> None:
    port = free_port()
    emulator, _ = _start([sys.executable, "-m", "armbench", "emulate", "--tcp",
                          f"127.0.0.1:{port}"], "serving the arm")
    try:
        node, _ = _start([sys.executable, "-m", "armbench", "-v", "ros2", "--port",
                          f"socket://127.0.0.1:{port}", "--connect-timeout", str(GUARD_S),
                          "--reply-timeout", "5"],  # the loss is the kill's, not a starved peer
                         "ROS 2 node 'armbench' serving")
        emulator.send_signal(signal.SIGTERM)
        out, _ = node.communicate(timeout=GUARD_S)
    finally:
        emulator.kill()
        emulator.wait()
    assert node.returncode == 1, out
    assert "link lost" in out and "Traceback" not in out
