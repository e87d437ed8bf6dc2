"""The node as a standard ROS 2 robot, with real rclpy and Fast DDS: the ``FollowJointTrajectory``
action served to a separate process with a plain rclpy ``ActionClient``
(:mod:`armbench.frontends.ros2_node.action_client`), ``/tf`` against the driver's forward
kinematics, and the message support built once and used from its cache by another process.

The node runs in this process on ``fake://`` (virtual time); each test has a ROS domain of its own
with discovery on this host only. The message support is the session's (``ros2_msgs`` in
``conftest.py``: built once, ~50 s on 2 cores). Waits on the graph are bounded by the client's
guard (``GUARD_S``, a hang guard only: on virtual time the emulator runs as fast as the host lets
it); what is asserted is judged on virtual time or counted in replies, never on real seconds.
"""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from armbench.drivers.model.kinematics import fk
from armbench.drivers.model.protocol import Command
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.frontends.ros2_node import missing_ros2

pytestmark = [pytest.mark.skipif(missing_ros2() is not None,
                                 reason=f"armbench[ros2] not installed: {missing_ros2()}"),
              pytest.mark.usefixtures("ros_domain")]  # a domain of its own (conftest.py)

S = RobotSettings()
NAMES = [j.name for j in S.joints]
CLIENT = [sys.executable, "-m", "armbench.frontends.ros2_node.action_client"]
#: Real seconds a client may take at most on a loaded machine (a hang guard).
GUARD_S = 120.0
#: A drive too weak to lift: joint 2 loses synchronism at speed (``fake://?settings=...``).
WEAK_DRIVE = '[emulator.physics.j2]\npullout_nm = 0.3\nloss_law = "stall"\n'


async def _process(argv: list[str]) -> dict[str, Any]:
    proc = await asyncio.create_subprocess_exec(*argv, stdout=asyncio.subprocess.PIPE,
                                                stderr=asyncio.subprocess.PIPE)
    out, err = await proc.communicate()
    assert proc.returncode == 0, (out.decode(), err.decode()[-2000:])
    result: dict[str, Any] = json.loads(out.decode().splitlines()[-1])
    return result


def _with_node(argv: list[str], port: str = "fake://",
               during: Callable[[Any], Awaitable[None]] | None = None,
               ) -> tuple[Any, Any, dict[str, Any], list[tuple[float, Command]]]:
    """The node on ``port`` while the process ``argv`` runs (and ``during(node)`` beside it): the
    node, its arm, the process's result and every command written to the arm (loop time)."""
    from armbench.frontends.ros2_node.node import ArmNode, NodeOptions, PublishingArm

    async def main() -> tuple[Any, Any, dict[str, Any], list[tuple[float, Command]]]:
        async with PublishingArm(port, S) as arm:
            node = ArmNode(arm, NodeOptions(clock=True))
            sent: list[tuple[float, Command]] = []
            publish = arm.on_command
            assert publish is not None

            def on_command(t: float, command: Command) -> None:
                sent.append((t, command))
                publish(t, command)

            arm.on_command = on_command
            serving = asyncio.ensure_future(node.run())
            side = asyncio.ensure_future(during(node)) if during is not None else None
            try:
                result = await _process(argv)
            finally:
                for task in (serving, side):
                    if task is not None:
                        task.cancel()
                        await asyncio.wait({task})
            return node, arm, result, sent

    return run_virtual(main())


def _goal(points: list[list[float]], times_s: list[float], **more: Any) -> str:
    return json.dumps({"names": NAMES, "points": points, "times_s": times_s, **more})


def _action(*goals: str, more: tuple[str, ...] = ()) -> list[str]:
    return [*CLIENT, *(a for g in goals for a in ("--goal", g)), "--timeout", str(GUARD_S),
            *more]


def test_a_three_point_goal_succeeds_with_the_arm_there_in_truth() -> None:
    target = [0.2, 0.3, -0.2, 0.4]
    tol = 0.02  # what the twin's mechanism (offsets, deflection) leaves between reply and truth
    goal = _goal([[0.1, 0.1, -0.1, 0.1], [0.15, 0.2, -0.15, 0.25], target], [1.0, 2.0, 3.0],
                 goal_tolerance={n: tol for n in NAMES})
    node, arm, got, _ = _with_node(_action(goal))
    assert (got["status"], got["error_code"]) == ("SUCCEEDED", 0), got
    truth = arm.ground_truth()
    assert truth is not None
    assert np.abs(np.array(truth.true_rad) - target).max() <= tol, (truth.true_rad, target)
    # feedback at the reply rate: desired, actual and error for the arm's joints
    assert got["feedback"] >= 50, got["feedback"]
    last = got["last_feedback"]
    assert last["joint_names"] == NAMES and len(last["actual"]["positions"]) == 4
    assert np.allclose(np.subtract(last["desired"]["positions"], last["actual"]["positions"]),
                       last["error"]["positions"])
    assert node.action.results == {1: 0}
    run = node.last_run
    assert run is not None and len(run.waypoints) == 3
    assert run.duration_s == pytest.approx(3.0, rel=0.1)  # the trajectory's time kept


def test_wrong_joint_names_are_invalid_joints_and_nothing_moves() -> None:
    goal = json.dumps({"names": ["a", "b", "c", "d"], "points": [[0.1] * 4], "times_s": [2.0]})
    node, _, got, sent = _with_node(_action(goal))
    assert (got["status"], got["error_code"]) == ("ABORTED", -2), got
    assert "joint_names" in got["error_string"]
    assert [c.duties for _, c in sent] == [(0, 0, 0, 0)]  # only the hold of the shutdown
    assert node.last_run is None


def test_an_invalid_goal_and_an_old_stamp_are_refused_before_motion() -> None:
    upper = S.joints[1].upper_rad
    beyond = _goal([[0.0, upper + 0.2, 0.0, 0.0]], [5.0])
    old = _goal([[0.1, 0.0, 0.0, 0.0]], [1.0], stamp_s=0.5)  # ended before now (virtual s)
    ok = _goal([[0.05, 0.0, 0.0, 0.0]], [1.0])

    _, _, got, sent = _with_node(_action(beyond, old, ok))
    codes = [(r["status"], r["error_code"]) for r in got["results"]]
    assert codes == [("ABORTED", -1), ("ABORTED", -3), ("SUCCEEDED", 0)], got["results"]
    assert NAMES[1] in got["results"][0]["error_string"]
    moving = [c for _, c in sent if any(c.duties)]
    assert len(moving) == 1  # the valid goal's one point only


def test_cancel_holds_the_arm_before_the_next_reply() -> None:
    """The cancel reaches the node, the arm is held at the same virtual instant (before the next
    reply is read), and the goal ends CANCELED with the arm standing still."""
    _cancel_and_check()


def test_a_cancel_rclpy_marks_late_still_ends_canceled(monkeypatch: pytest.MonkeyPatch) -> None:
    """rclpy marks a goal cancel-requested only after the node's cancel callback has returned, on
    another executor thread; the node holds the arm at once and ends the goal CANCELED when the
    mark comes. Here the mark is held back half a second (a loaded machine's thread switch, made
    certain), so the goal's end on the loop comes before it."""
    from rclpy.action.server import GoalEvent, ServerGoalHandle

    marked = ServerGoalHandle._update_state
    held_back = 0

    def mark_late(handle: Any, event: Any) -> None:
        nonlocal held_back
        if event == GoalEvent.CANCEL_GOAL:
            held_back += 1
            time.sleep(0.5)
        marked(handle, event)

    monkeypatch.setattr(ServerGoalHandle, "_update_state", mark_late)
    _cancel_and_check()
    assert held_back == 1  # the delay was on the cancel's path


def test_a_cancel_that_comes_after_the_goal_ended_leaves_nothing(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """rclpy may hand the node a cancel of a goal that another executor thread is ending; here
    the node's cancel callback gets the goal's own handle after the goal succeeded (the race
    made certain): the goal stays SUCCEEDED and the node keeps no record of the cancel."""
    from armbench.frontends.ros2_node.follow_action import FollowServer

    handles: list[Any] = []
    execute = FollowServer._execute

    def keep(server: FollowServer, handle: Any) -> Any:
        handles.append(handle)
        return execute(server, handle)

    monkeypatch.setattr(FollowServer, "_execute", keep)
    left: list[set[bytes]] = []

    async def cancel_late(node: Any) -> None:
        # ended in rclpy's own state (the node notes its result code a moment before)
        while not handles or handles[0].is_active or not node.action.results:
            await asyncio.sleep(0.01)
        node.action._cancel(handles[0])
        left.append(set(node.action._cancels))

    node, _, got, _ = _with_node(_action(_goal([[0.1, 0.0, 0.0, 0.0]], [1.0])),
                                 during=cancel_late)
    assert (got["status"], node.action.results) == ("SUCCEEDED", {1: 0}), got
    assert left == [set()]


def _cancel_and_check() -> None:
    slow = _goal([[1.5, 0.0, 0.0, 0.0]], [60.0])
    node, arm, got, sent = _with_node(_action(slow, more=("--cancel-after", "20")))
    assert got["cancel"]["goals_canceling"] == 1
    assert got["status"] == "CANCELED", got
    holds = [(t, c) for t, c in sent if not any(c.duties)]
    cancelled_at = node.action.cancelled_at
    assert len(cancelled_at) == 1
    t_cancel = next(iter(cancelled_at.values()))
    t_hold = min(t for t, _ in holds if t >= t_cancel)
    # the hold went out at the cancel's loop time: no reply came in between (replies are
    # ~2.4 ms of virtual time apart)
    assert t_hold - t_cancel < 1e-3, (t_cancel, t_hold)
    q = np.array(arm.state.q_rad)
    assert 0.0 < q[0] < 1.5  # stopped on the way
    assert "holds at" in got["error_string"]
    assert not node.action._cancels  # the ended goal's cancel is let go


def test_a_new_goal_preempts_the_running_one() -> None:
    slow = _goal([[1.5, 0.0, 0.0, 0.0]], [60.0])
    target = [0.0, 0.1, 0.0, 0.0]
    fast = _goal([target], [3.0])
    _, arm, got, _ = _with_node(_action(slow, fast))
    first, second = got["results"]
    assert (first["status"], second["status"]) == ("ABORTED", "SUCCEEDED"), got
    assert first["error_code"] == -1  # INVALID_GOAL, as ros2_control's controller gives it
    assert "replaced by goal 2" in first["error_string"]
    tol = arm.default_tolerance_rad()
    assert all(abs(a - b) <= e for a, b, e in zip(arm.state.q_rad, target, tol, strict=True))


def test_a_stall_violates_the_path_tolerance_and_the_arm_is_held(tmp_path: Path) -> None:
    weak = tmp_path / "weak.toml"
    weak.write_text(WEAK_DRIVE)
    goal = _goal([[0.0, 0.8, 0.0, 0.0]], [4.0])  # what the default arm follows
    _, arm, got, sent = _with_node(_action(goal), port=f"fake://?settings={weak}")
    assert (got["status"], got["error_code"]) == ("ABORTED", -4), got
    assert "j2" in got["error_string"] and "path tolerance" in got["error_string"]
    # held: the one point's command (resent while the joint stalled: the driver's arrival
    # tracking), then holds only (the violation's, the shutdown's)
    duties = [c.duties for _, c in sent]
    moving = [d for d in duties if any(d)]
    assert moving and set(moving) == {moving[0]}, duties
    assert duties[:len(moving)] == moving and not any(map(any, duties[len(moving):])), duties
    assert arm.state.q_rad[1] < 0.8 - 0.1  # joint 2 stopped short of the goal


def _compose(transforms: list[list[Any]], child: str) -> np.ndarray:
    """The pose of ``child`` in ``base_link`` (4x4) from (parent, child, pose) transforms."""
    by_child = {c: (p, pose) for p, c, pose in transforms}
    out = np.eye(4)
    while child != "base_link":
        parent, (tx, ty, tz, qx, qy, qz, qw) = by_child[child]
        m = np.eye(4)
        m[:3, :3] = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()  # scalar last
        m[:3, 3] = [tx, ty, tz]
        out = m @ out
        child = parent
    return out


def test_tf_is_the_drivers_forward_kinematics() -> None:
    """``/tf`` with ``/tf_static``, for the joint state of the same stamp, composes to the
    driver's forward kinematics to 1e-9 m, while the arm moves; ``/joint_states`` carries
    velocities."""
    async def move(node: Any) -> None:
        while not all(p.get_subscription_count() for p in (node._pub_tf, node._pub_js)):
            await asyncio.sleep(0.01)  # the listener matched: it sees the move
        await node.arm.move_joints([0.4, 0.3, -0.3, 0.5], duty=60)

    listener = [sys.executable, str(Path(__file__).with_name("ros2_tf_listener.py")), "400",
                str(GUARD_S)]
    _, _, got, _ = _with_node(listener, during=move)
    worst, moving = 0.0, 0
    for pair in got["pairs"]:
        pose = _compose(got["static"] + pair["tf"], "link4")
        worst = max(worst, float(np.abs(pose - fk(pair["q"], S)).max()))
        moving += any(abs(v) > 0 for v in pair["velocity"])
    assert worst < 1e-9, worst
    assert {c for _, c, _ in got["static"]} == {f"link{i}" for i in range(1, 5)}
    assert moving > 0  # the listener saw the arm move, with velocities


def test_the_cache_serves_a_second_process_and_a_users_script(
        ros2_msgs: dict[str, object], tmp_path: Path) -> None:
    """``armbench ros2 build-msgs`` in another process finds the session's build (no build),
    and a plain script imports control_msgs and tf2_msgs after ``eval "$(armbench ros2 env)"``."""
    env = {**os.environ, "XDG_CACHE_HOME": str(ros2_msgs["xdg"])}
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "armbench", "ros2", "build-msgs"], env=env,
                          capture_output=True, text=True, timeout=GUARD_S, check=True)
    again = json.loads(done.stdout)
    assert again["built_s"] is None and again["prefix"] == str(ros2_msgs["prefix"]), again
    print(f"\nmessage support: built in {ros2_msgs['built_s']} s in this session; cache hit "
          f"{again['elapsed_s']} s in the process, {time.perf_counter() - t0:.2f} s the command")
    script = tmp_path / "user.py"
    script.write_text("from control_msgs.action import FollowJointTrajectory\n"
                      "from tf2_msgs.msg import TFMessage\n"
                      "print(FollowJointTrajectory.Result.INVALID_JOINTS, TFMessage.__name__)\n")
    shell = (f'eval "$({sys.executable} -m armbench ros2 env)" && '
             f"{sys.executable} {script}")
    user = subprocess.run(["bash", "-c", shell], env=env, capture_output=True, text=True,
                          timeout=GUARD_S, check=False)
    assert user.returncode == 0, user.stderr[-2000:]
    assert user.stdout.split() == ["-2", "TFMessage"]


def test_a_process_that_inherits_the_path_loads_the_libraries(ros2_msgs: dict[str, object],
                                                                tmp_path: Path) -> None:
    """A worker process started with its parent's ``sys.path`` finds the built packages on it but
    not their libraries: armbench loads them (a bench run's workers once failed with
    ``UnsupportedTypeSupport``)."""
    from armbench.frontends.ros2_node.msgs_build import _site_packages

    prefix = ros2_msgs["prefix"]
    assert isinstance(prefix, Path)
    probe = ("from armbench.frontends.ros2_node.msgs_build import ensure_messages\n"
             "support = ensure_messages(build=False)\n"
             "import rclpy\nfrom tf2_msgs.msg import TFMessage\n"
             "rclpy.init()\nnode = rclpy.create_node('inherits')\n"
             "node.create_publisher(TFMessage, 'tf', 1).publish(TFMessage())\n"
             "print(support.prefix)\n")
    env = {**os.environ, "PYTHONPATH": str(_site_packages(prefix)),
           "XDG_CACHE_HOME": str(tmp_path / "elsewhere")}  # not the cache: the path only
    done = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True,
                          timeout=GUARD_S, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == str(prefix)
