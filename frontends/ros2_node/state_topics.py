"""The messages of the arm's state the node publishes: ``/joint_states`` with velocities, ``/tf``
and ``/tf_static`` from the URDF's kinematics, and the action's feedback.

The frames and their names are the MCAP capture's (:mod:`armbench.drivers.model.ros2`): ``/tf``
turns ``link{i}_root`` in its parent by joint ``i``'s DH angle, ``/tf_static`` fixes DH frame
``link{i}`` to it, so ``base_link`` → ``link4`` is the driver's forward kinematics
(:func:`armbench.drivers.model.kinematics.fk`) and a ``robot_state_publisher`` given the URDF and
``/joint_states`` computes the same. A joint's velocity is the change of its position over the
time between two replies with different times (replies read in one chunk share a time: they
repeat the last velocity; the first reply has none: 0).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from armbench.drivers.host.arm import JointState
from armbench.drivers.model import ros2
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.urdf import robot_urdf
from armbench.fakes.firmware.emulator_settings import emulator_settings

__all__ = ["StateMessages", "fill_feedback", "node_urdf", "time_msg"]


def time_msg(msg: Any, t_s: float) -> None:
    """Set a ``builtin_interfaces/Time`` to ``t_s`` seconds (whole nanoseconds, not before 0)."""
    ns = max(0, round(t_s * 1e9))
    msg.sec, msg.nanosec = divmod(ns, 1_000_000_000)


def node_urdf(settings: RobotSettings) -> str:
    """The URDF ``/robot_description`` serves and ``armbench urdf`` prints: with the efforts and
    masses of the settings' twin (``[emulator.physics]``; none for the ideal profile)."""
    physics = emulator_settings(settings).physics
    return robot_urdf(settings, twin=None if physics is None else physics.joints)


def _transform(msg: Any, parent: str, child: str, pose: Sequence[float]) -> None:
    msg.header.frame_id, msg.child_frame_id = parent, child
    t, r = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = pose[0], pose[1], pose[2]
    r.x, r.y, r.z, r.w = pose[3], pose[4], pose[5], pose[6]


class StateMessages:
    """Fills the node's state messages (the message classes are the caller's: rclpy's)."""

    def __init__(self, settings: RobotSettings, joint_state: Any, tf_message: Any,
                 transform: Any) -> None:
        self.settings = settings
        self.names = [j.name for j in settings.joints]
        self._transform = transform
        self.joint_state = joint_state()
        self.joint_state.name = list(self.names)
        self.tf = tf_message()
        self.tf.transforms = [transform() for _ in ros2.MOVING_PAIRS]
        self._tf_message = tf_message
        self._last: tuple[float, Sequence[float]] | None = None
        self._velocity = [0.0] * len(self.names)

    def velocity(self, state: JointState) -> list[float]:
        """The joints' velocities (rad/s) at ``state`` (see the module doc)."""
        last = self._last
        if last is not None and state.t_s > last[0]:
            dt = state.t_s - last[0]
            self._velocity = [(q - p) / dt for q, p in zip(state.q_rad, last[1], strict=True)]
        if last is None or state.t_s > last[0]:
            self._last = (state.t_s, state.q_rad)
        return self._velocity

    def fill(self, state: JointState, stamp_s: float) -> None:
        """``joint_state`` and ``tf`` for ``state``, stamped ``stamp_s``."""
        js = self.joint_state
        time_msg(js.header.stamp, stamp_s)
        js.position = list(state.q_rad)
        js.velocity = self.velocity(state)
        for msg, (parent, child), pose in zip(self.tf.transforms, ros2.MOVING_PAIRS,
                                              ros2.link_transforms(state.q_rad, self.settings),
                                              strict=True):
            time_msg(msg.header.stamp, stamp_s)
            _transform(msg, parent, child, pose)

    def tf_static(self, stamp_s: float) -> Any:
        """The ``/tf_static`` message: the links fixed to their joints' frames."""
        out = self._tf_message()
        for (parent, child), pose in zip(ros2.STATIC_PAIRS,
                                         ros2.static_transforms(self.settings), strict=True):
            msg = self._transform()
            time_msg(msg.header.stamp, stamp_s)
            _transform(msg, parent, child, pose)
            out.transforms.append(msg)
        return out


def fill_feedback(msg: Any, point: Any, names: Sequence[str], stamp_s: float,
                  desired: Sequence[float], speed: Sequence[float], state: JointState,
                  velocity: Sequence[float], index: int, t_s: float) -> None:
    """A ``FollowJointTrajectory.Feedback``: desired, actual and error (desired − actual, as
    ros2_control's controller gives it) at ``t_s`` from the start; ``point`` makes
    ``JointTrajectoryPoint`` messages."""
    time_msg(msg.header.stamp, stamp_s)
    msg.joint_names = list(names)
    msg.index = index
    for field, positions, velocities in (
            ("desired", desired, speed), ("actual", state.q_rad, velocity),
            ("error", [d - a for d, a in zip(desired, state.q_rad, strict=True)],
             [d - a for d, a in zip(speed, velocity, strict=True)])):
        p = point()
        p.positions = [float(v) for v in positions]
        p.velocities = [float(v) for v in velocities]
        ns = max(0, round(t_s * 1e9))
        p.time_from_start.sec, p.time_from_start.nanosec = divmod(ns, 1_000_000_000)
        setattr(msg, field, p)
