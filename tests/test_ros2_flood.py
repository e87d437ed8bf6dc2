"""``armbench ros2`` under clients that flood it with trajectories (issue 38): real rclpy and Fast
DDS, the node as the command (a process of its own, ``fake://`` on virtual time) and the clients
as processes (``armbench.frontends.ros2_node.client flood``).

Each client first sends a pose and, once done, the same pose again (the arm is there: before, this
froze ``/joint_states`` for good and grew the node by ~28 MB/s), then its trajectories with
``header.stamp`` zero, a third of them to where the arm is. Two such clients at once must each
get exactly one final status for every one of theirs (told apart by their source, not the stamp),
``/joint_states`` must flow on after, and the node's memory must stay within 50 MB of its start.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from armbench.frontends.ros2_node import missing_ros2

pytestmark = [pytest.mark.skipif(missing_ros2() is not None,
                                 reason=f"armbench[ros2] not installed: {missing_ros2()}"),
              pytest.mark.usefixtures("ros_domain")]  # a domain of its own (conftest.py)

CLIENT = [sys.executable, "-m", "armbench.frontends.ros2_node.client"]
#: Real seconds a client or the command may take at most on a loaded machine (a hang guard).
GUARD_S = 120.0
#: How far the node's resident memory may grow over the test (MB).
RSS_GROWTH_MB = 50.0


def _rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


def _serve(log: Path) -> subprocess.Popen[bytes]:
    """``armbench -v ros2 --port fake://``, its output to ``log`` (a pipe nobody reads would
    hold the node up once full), once it serves."""
    with log.open("wb") as out:
        node = subprocess.Popen([sys.executable, "-m", "armbench", "-v", "ros2", "--port",
                                 "fake://"], stdout=out, stderr=subprocess.STDOUT)
    deadline = time.monotonic() + GUARD_S
    while "ROS 2 node 'armbench' serving" not in log.read_text():
        assert node.poll() is None and time.monotonic() < deadline, log.read_text()[-3000:]
        time.sleep(0.1)
    return node


def _flood(node: subprocess.Popen[bytes], count: int) -> tuple[list[dict[str, Any]], float,
                                                               float]:
    """Two flood clients against the node: one sends a pose twice (waited for), then its
    trajectories one status at a time; once its pose is done twice, the other sends its own back
    to back. Their results, the node's memory at the start and the most it had (MB)."""
    rss0 = peak = _rss_mb(node.pid)
    procs: list[subprocess.Popen[str]] = []
    for args in (["--twice", "--window", "1"], []):
        procs.append(subprocess.Popen(
            [*CLIENT, "flood", "--count", str(count), *args, "--timeout", str(GUARD_S)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        if args:  # the pose twice first, with nobody else moving the arm
            assert procs[0].stdout is not None
            assert "again" in procs[0].stdout.readline(), procs[0].communicate()
    deadline = time.monotonic() + GUARD_S + 30
    while any(p.poll() is None for p in procs) and time.monotonic() < deadline:
        peak = max(peak, _rss_mb(node.pid))
        time.sleep(0.2)
    results = []
    for p in procs:
        out, err = p.communicate(timeout=30)
        assert p.returncode == 0, (out[-2000:], err[-2000:])
        results.append(json.loads(out.splitlines()[-1]))
    return results, rss0, max(peak, _rss_mb(node.pid))


@pytest.mark.parametrize("count", [100, 1000])
def test_a_flood_gets_one_final_status_each_and_leaves_the_node_streaming_and_small(
        count: int, tmp_path: Path) -> None:
    log = tmp_path / "node.log"
    node = _serve(log)
    try:
        results, rss0, peak = _flood(node, count)
    finally:
        node.send_signal(signal.SIGTERM)
        node.wait(timeout=GUARD_S)
    assert node.returncode == 0, log.read_text()[-3000:]
    # the pose, then the same pose again: done at once, nothing moved, and the stream flowed on
    paced, back_to_back = results
    assert paced["first"]["state"] == "done" and paced["again"]["state"] == "done", paced
    assert paced["again"]["duration_s"] == 0.0 and paced["again"]["states"] == 0, paced
    for got in results:
        assert got["missing"] == [] and got["duplicates"] == [], got
        assert sum(got["finals"].values()) == count, got["finals"]
        assert got["states_after"] >= 100
    assert paced["gid"] != back_to_back["gid"]  # two clients, zero stamps, each its own
    print(f"flood of {count} x2: finals {[r['finals'] for r in results]}, node RSS "
          f"{rss0:.1f} MB at start, {peak:.1f} MB at most")
    assert peak - rss0 < RSS_GROWTH_MB, (rss0, peak)
