"""``armbench ros2``: the arm as a ROS 2 node (``/joint_states``, ``/tf``, ``/robot_description``,
the ``FollowJointTrajectory`` action at ``/<controller>/follow_joint_trajectory``, its alias
``/armbench/joint_trajectory``, ``/clock`` on emulated targets); ``armbench ros2 build-msgs`` and
``armbench ros2 env``: the message support of control_msgs and tf2_msgs, built once. The accuracy
square through ROS 2 against the driver's own run is the suite ``armbench run ros2-square``.

Needs the extra ``armbench[ros2]`` (rclpy and the message packages from pip); without it the
command says so in one line (exit 2). Against ``fake://`` the emulator runs in-process on virtual
time and the node publishes ``/clock``. See ``docs/ros.md``.
"""

from __future__ import annotations

import argparse
import asyncio
import signal
import time
from typing import Any

from armbench.cli.commands.bounds import DURATION_S, REPLY_TIMEOUT_S, TIMEOUT_S, add_bounded
from armbench.cli.commands.monitor import run_on_port
from armbench.drivers.host.link import CONNECT_TIMEOUT_S
from armbench.drivers.model.bounds import Bound
from armbench.drivers.model.errors import InvalidTargetError
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import RobotSettings, load_settings
from armbench.drivers.transports.target import target_of
from armbench.frontends.ros2_node.names import namespace_problem, node_name_problem

__all__ = ["REALTIME_FACTOR", "register"]

#: ``--realtime-factor``: a thousand times slower than real time (a reply every ~2.4 s) to a
#: million times faster (no holding back at all).
REALTIME_FACTOR = Bound(0.001, 1e6)


def register(sub: Any) -> None:
    """Add the ``ros2`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "ros2",
        description="Serve the arm on PORT as a ROS 2 node: /joint_states (with velocities) "
                    "and /tf at the arm's reply rate, /tf_static and /robot_description (URDF, "
                    "transient local), the control_msgs FollowJointTrajectory action at "
                    "/CONTROLLER/follow_joint_trajectory executed with the driver's coordinated "
                    "streaming (and its alias /armbench/joint_trajectory with "
                    "/armbench/trajectory_status), /joint_states_goal, /armbench/events, and "
                    "/clock from the virtual clock on fake://. Stops the arm on exit. The first "
                    "start builds the message support (about a minute; see build-msgs).",
        epilog="Exit status: 0 after --duration or SIGTERM (the arm stopped), 130 after Ctrl-C "
               "(SIGINT; the arm stopped too), 1 when the port is lost, 2 for bad options or a "
               "missing ros2 extra.")
    p.add_argument("--port", default="fake://",
                   help="any port armbench speaks: serial device, socket://, rfc2217://, "
                        "labgrid://, avr:// or fake:// (default, the emulator on virtual time)")
    p.add_argument("--settings", default=None, metavar="FILE", help="robot settings TOML")
    add_bounded(p, "--duration", DURATION_S, default=None, metavar="S",
                help="serve S seconds (loop time: simulated seconds on fake://), default: until "
                     "Ctrl-C or SIGTERM")
    p.add_argument("--node-name", default="armbench",
                   help="ROS node name: letters, digits and _, not starting with a digit "
                        "(default armbench)")
    p.add_argument("--namespace", default="", metavar="NS",
                   help="the node's namespace: its topics resolve under it (default: /, so "
                        "/joint_states); one per arm when several share a graph")
    p.add_argument("--controller", default="arm_controller", metavar="NAME",
                   help="the FollowJointTrajectory action's namespace: "
                        "/NAME/follow_joint_trajectory (default arm_controller, the name "
                        "MoveIt's simple controller manager and ros2_control use)")
    add_bounded(p, "--domain-id", Bound(0, 232, whole=True), default=None, metavar="N",
                help="ROS domain (default: ROS_DOMAIN_ID, else 0)")
    add_bounded(p, "--max-duty", Bound(1, MAX_DUTY, whole=True), default=MAX_DUTY, metavar="V",
                help="refuse trajectory segments that need a duty above V (default 99)")
    add_bounded(p, "--realtime-factor", REALTIME_FACTOR, default=None, metavar="X",
                help=f"fake://: at most X simulated seconds per real second, X in "
                     f"{REALTIME_FACTOR} (default: as fast as the emulator runs)")
    add_bounded(p, "--history-depth", Bound(2, 1_000_000, whole=True), default=10_000,
                metavar="N", help="/joint_states messages kept for a subscriber that has not "
                                  "acknowledged them (default 10000); beyond it the oldest go "
                                  "first")
    p.add_argument("--slow-subscriber", choices=("pace", "drop"), default="pace",
                   help="fake://: when a subscriber of /joint_states falls behind, hold the "
                        "virtual clock until it has caught up (pace, default) or run on and let "
                        "it lose the oldest (drop); real time always drops")
    add_bounded(p, "--pace-timeout", TIMEOUT_S, default=5.0, metavar="S",
                help="pace: stop waiting for a subscriber that acknowledges nothing for S real "
                     "seconds (default 5)")
    add_bounded(p, "--connect-timeout", TIMEOUT_S, default=CONNECT_TIMEOUT_S, metavar="S",
                help=f"wait S s for the arm's first reply (default {CONNECT_TIMEOUT_S:g})")
    add_bounded(p, "--reply-timeout", REPLY_TIMEOUT_S, default=0.5, metavar="S",
                help="hold the arm and report it silent after S s without a reply")
    p.set_defaults(func=_run)
    actions = p.add_subparsers(dest="ros2_action", metavar="{build-msgs,env}",
                               help="without one: serve the arm")
    b: argparse.ArgumentParser = actions.add_parser(
        "build-msgs",
        description="Build the message support of control_msgs (FollowJointTrajectory) and "
                    "tf2_msgs (TFMessage) into the user cache, once per environment (about a "
                    "minute; needs cmake and a C/C++ compiler); an installed control_msgs or "
                    "tf2_msgs is used instead. Prints where it is and the time taken.")
    b.set_defaults(func=_build_msgs)
    e: argparse.ArgumentParser = actions.add_parser(
        "env",
        description="Print the shell lines that let any Python of this environment import the "
                    "built control_msgs and tf2_msgs: eval \"$(armbench ros2 env)\". Builds "
                    "them first if needed.")
    e.set_defaults(func=_env)


def _build_msgs(args: argparse.Namespace) -> int:
    import json
    import sys

    from armbench.frontends.ros2_node import require_rclpy
    from armbench.frontends.ros2_node.msgs_build import ensure_messages

    require_rclpy()
    t0 = time.perf_counter()
    support = ensure_messages(progress=lambda m: print(m, file=sys.stderr, flush=True))
    print(json.dumps({"prefix": None if support.prefix is None else str(support.prefix),
                      "installed": list(support.installed), "built_s": support.built_s,
                      "elapsed_s": round(time.perf_counter() - t0, 3)}))
    return 0


def _env(args: argparse.Namespace) -> int:
    import sys

    from armbench.frontends.ros2_node import require_rclpy
    from armbench.frontends.ros2_node.msgs_build import ensure_messages, env_lines

    require_rclpy()
    support = ensure_messages(progress=lambda m: print(m, file=sys.stderr, flush=True))
    sys.stdout.write(env_lines(support))
    return 0


def _check(args: argparse.Namespace) -> None:
    """The options a bound does not cover (:mod:`armbench.cli.commands.bounds` checks the
    numbers)."""
    for flag, value, problem in (("--node-name", args.node_name, node_name_problem),
                                 ("--namespace", args.namespace, namespace_problem),
                                 ("--controller", args.controller, node_name_problem)):
        why = problem(value)
        if why is not None:
            raise InvalidTargetError(None, flag, value, why)


def _run(args: argparse.Namespace) -> int:
    _check(args)
    from armbench.frontends.ros2_node import require_rclpy

    require_rclpy()
    import sys

    from armbench.frontends.ros2_node.msgs_build import ensure_messages
    from armbench.frontends.ros2_node.node import NodeOptions

    # before the arm is opened: a first build takes about a minute
    ensure_messages(progress=lambda m: print(m, file=sys.stderr, flush=True))

    settings = load_settings(args.settings)
    options = NodeOptions(node_name=args.node_name, namespace=args.namespace,
                          clock=target_of(args.port).virtual,
                          max_duty=args.max_duty, domain_id=args.domain_id,
                          realtime_factor=args.realtime_factor,
                          history_depth=args.history_depth, slow_subscriber=args.slow_subscriber,
                          pace_timeout_s=args.pace_timeout, controller=args.controller)
    return run_on_port(args.port, _serve(args, settings, options))


async def _serve(args: argparse.Namespace, settings: RobotSettings, options: Any) -> int:
    from armbench.frontends.ros2_node.node import ArmNode, PublishingArm

    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    assert task is not None
    terminated = False

    def on_term() -> None:
        nonlocal terminated
        terminated = True
        task.cancel()

    async with PublishingArm(args.port, settings, reply_timeout_s=args.reply_timeout,
                             connect_timeout_s=args.connect_timeout) as arm:
        node = ArmNode(arm, options)
        loop.add_signal_handler(signal.SIGTERM, on_term)
        try:
            return await node.run(args.duration)
        except asyncio.CancelledError:
            if terminated:
                task.uncancel()  # handled: the arm's connection closes as on a normal end
                return 0
            raise
        finally:
            loop.remove_signal_handler(signal.SIGTERM)
