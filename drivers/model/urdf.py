"""The arm as a URDF from the DH table and the robot settings, for RViz, Foxglove and planners.

The kinematic tree is the standard-DH chain of :mod:`armbench.drivers.model.kinematics`: joint
``j{i}`` (revolute, axis ``±z`` by the joint's ``sign``, origin turned by its ``offset_rad``) turns
frame ``link{i}_root`` in its parent (``base_link`` or ``link{i-1}``); DH frame ``i`` is the link
``link{i}``, fixed to the root by ``Tz(d_i)·Tx(a_i)·Rx(α_i)``. So a joint position is the
protocol angle the driver reports (``JointState`` of ``/joint_states``) and the origin of
``link4`` is the TCP.

Limits a planner can use: position from the settings (protocol convention); velocity the joint's
speed at the fastest duty by speed law (12) (:data:`~armbench.drivers.model.protocol.MAX_DUTY`:
one motor step every two 80 µs cycles); effort the joint torque the twin's stepper can lift with
(pull-out torque at standstill × gear ratio × worm efficiency) when a ``twin`` is given, else
:data:`NOMINAL_EFFORT_NM`. Geometry is simple shapes, the same for ``visual`` and ``collision``: a
box for the base, cylinders of :data:`LINK_RADIUS_M` along each DH offset. Each moving link has an
``inertial``: the twin's link mass (:data:`NOMINAL_LINK_MASS_KG` where it has none) at its centre
of mass fraction along the link's segment, the inertia of a solid cylinder of that mass, the link's
radius and its segment's length. A ``<ros2_control>`` block names the joints with their position
command interface (the limits) and position and velocity state interfaces; its hardware is
ros2_control's mock system (the arm itself is served by ``armbench ros2``, not by a ros2_control
hardware plugin).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final, Protocol
from xml.sax.saxutils import quoteattr

from armbench.drivers.model.kinematics import dh_parameters
from armbench.drivers.model.protocol import CYCLE_S, MAX_DUTY
from armbench.drivers.model.ros2 import link_names
from armbench.drivers.model.settings import JointSettings, RobotSettings

__all__ = ["BASE_SIZE_M", "LINK_RADIUS_M", "NOMINAL_EFFORT_NM", "NOMINAL_LINK_MASS_KG",
           "TwinJoint", "joint_effort_nm", "joint_velocity_rad_s", "robot_urdf"]

#: Radius of the cylinders drawn along the DH offsets (m).
LINK_RADIUS_M: Final = 0.03
#: Side of the base's box (m; half as high).
BASE_SIZE_M: Final = 0.12
#: The ``effort`` limit written where no twin gives one (N·m): nominal, for tools that need one.
NOMINAL_EFFORT_NM: Final = 10.0
#: A link's mass where the twin has none (kg): simulators and planners need a positive one.
NOMINAL_LINK_MASS_KG: Final = 0.1
#: ros2_control's hardware named in the ``<ros2_control>`` block.
HARDWARE_PLUGIN: Final = "mock_components/GenericSystem"

_COLOURS: Final = {"base": "0.3 0.3 0.3 1", "link": "0.95 0.55 0.1 1"}


class TwinJoint(Protocol):
    """What the URDF reads of a joint of the twin
    (:class:`armbench.fakes.twin.physics.JointPhysics`)."""

    @property
    def mass_kg(self) -> float: ...

    @property
    def com_fraction(self) -> float: ...

    @property
    def pullout_nm(self) -> float: ...

    @property
    def efficiency(self) -> float: ...


def _num(x: float) -> str:
    return repr(float(x))


def _origin(xyz: Sequence[float], rpy: Sequence[float]) -> str:
    return (f'<origin xyz="{" ".join(_num(v) for v in xyz)}" '
            f'rpy="{" ".join(_num(v) for v in rpy)}"/>')


def joint_velocity_rad_s(joint: JointSettings) -> float:
    """The joint's speed at duty :data:`MAX_DUTY` by law (12): ``1 / ((101 − 99) · 80 µs)``
    motor steps per second over its steps per radian."""
    return 1.0 / ((101 - MAX_DUTY) * CYCLE_S) / joint.steps_per_rad


def joint_effort_nm(joint: JointSettings, twin: TwinJoint | None) -> float:
    """The joint torque the twin's stepper can lift with: pull-out torque at standstill × gear
    ratio × worm efficiency; :data:`NOMINAL_EFFORT_NM` without a twin or a finite pull-out."""
    if twin is None or not math.isfinite(twin.pullout_nm):
        return NOMINAL_EFFORT_NM
    return twin.pullout_nm * joint.gear_ratio * twin.efficiency


def _shapes(a_m: float, d_m: float) -> list[tuple[float, tuple[float, ...], tuple[float, ...]]]:
    """``(length, xyz, rpy)`` of the cylinders from ``link{i}_root`` along ``d`` (its z axis)
    then ``a`` (its x axis)."""
    out: list[tuple[float, tuple[float, ...], tuple[float, ...]]] = []
    if abs(d_m) > 1e-9:
        out.append((abs(d_m), (0.0, 0.0, d_m / 2), (0.0, 0.0, 0.0)))
    if abs(a_m) > 1e-9:
        out.append((abs(a_m), (a_m / 2, 0.0, d_m), (0.0, math.pi / 2, 0.0)))
    return out


def _cylinders(a_m: float, d_m: float) -> str:
    out = ""
    for length, xyz, rpy in _shapes(a_m, d_m):
        geometry = (f'<geometry><cylinder radius="{_num(LINK_RADIUS_M)}" '
                    f'length="{_num(length)}"/></geometry>')
        out += (f'    <visual>{_origin(xyz, rpy)}{geometry}<material name="link"/></visual>\n'
                f"    <collision>{_origin(xyz, rpy)}{geometry}</collision>\n")
    return out


def _inertial(a_m: float, d_m: float, twin: TwinJoint | None) -> str:
    mass = twin.mass_kg if twin is not None and twin.mass_kg > 0 else NOMINAL_LINK_MASS_KG
    f = twin.com_fraction if twin is not None else 0.5
    length = max(abs(a_m) + abs(d_m), LINK_RADIUS_M)
    r2 = LINK_RADIUS_M ** 2
    across = mass * (3.0 * r2 + length ** 2) / 12.0
    along = mass * r2 / 2.0
    # the cylinder's axis: the link's longer offset (x for ``a``, z for ``d``)
    ixx, izz = (along, across) if abs(a_m) > abs(d_m) else (across, along)
    return (f"    <inertial>{_origin((f * a_m, 0.0, f * d_m), (0.0, 0.0, 0.0))}"
            f'<mass value="{_num(mass)}"/><inertia ixx="{_num(ixx)}" ixy="0.0" ixz="0.0" '
            f'iyy="{_num(across)}" iyz="0.0" izz="{_num(izz)}"/></inertial>\n')


def _ros2_control(settings: RobotSettings, name: str) -> str:
    joints = "".join(
        f"    <joint name={quoteattr(j.name)}>\n"
        f'      <command_interface name="position"><param name="min">{_num(j.lower_rad)}'
        f'</param><param name="max">{_num(j.upper_rad)}</param></command_interface>\n'
        '      <state_interface name="position"/><state_interface name="velocity"/>\n'
        "    </joint>\n" for j in settings.joints)
    return (f'  <ros2_control name={quoteattr(name)} type="system">\n'
            f"    <hardware><plugin>{HARDWARE_PLUGIN}</plugin></hardware>\n"
            f"{joints}  </ros2_control>\n")


def robot_urdf(settings: RobotSettings, name: str = "robolink", *,
               twin: Sequence[TwinJoint] | None = None) -> str:
    """The URDF text of the arm described by ``settings``; ``twin``: the twin's joints, for the
    efforts and masses (see the module doc)."""
    table = dh_parameters(settings.geometry)
    twins: Sequence[TwinJoint | None] = twin if twin is not None else [None] * len(settings.joints)
    parts = [f'<?xml version="1.0"?>\n<robot name={quoteattr(name)}>\n']
    parts += [f'  <material name="{k}"><color rgba="{v}"/></material>\n'
              for k, v in _COLOURS.items()]
    base = BASE_SIZE_M
    box = f'<geometry><box size="{base} {base} {base / 2}"/></geometry>'
    parts.append(f'  <link name="base_link">\n'
                 f'    <visual>{_origin((0, 0, base / 4), (0, 0, 0))}{box}'
                 '<material name="base"/></visual>\n'
                 f"    <collision>{_origin((0, 0, base / 4), (0, 0, 0))}{box}</collision>\n"
                 "  </link>\n")
    for i, (joint, (a, alpha, d), tj) in enumerate(zip(settings.joints, table, twins,
                                                        strict=True), 1):
        parent, root, link = link_names(i)
        a_m, d_m = float(a), float(d)
        parts.append(
            f'  <joint name={quoteattr(joint.name)} type="revolute">\n'
            f'    <parent link="{parent}"/><child link="{root}"/>\n'
            f'    {_origin((0.0, 0.0, 0.0), (0.0, 0.0, joint.offset_rad))}\n'
            f'    <axis xyz="0 0 {joint.sign}"/>\n'
            f'    <limit lower="{_num(joint.lower_rad)}" upper="{_num(joint.upper_rad)}" '
            f'effort="{_num(joint_effort_nm(joint, tj))}" '
            f'velocity="{_num(joint_velocity_rad_s(joint))}"/>\n'
            f'  </joint>\n'
            f'  <link name="{root}">\n{_inertial(a_m, d_m, tj)}{_cylinders(a_m, d_m)}'
            "  </link>\n"
            f'  <joint name="{link}_fixed" type="fixed">\n'
            f'    <parent link="{root}"/><child link="{link}"/>\n'
            f'    {_origin((a_m, 0.0, d_m), (float(alpha), 0.0, 0.0))}\n'
            f'  </joint>\n'
            f'  <link name="{link}"/>\n')
    parts.append(_ros2_control(settings, name))
    parts.append("</robot>\n")
    return "".join(parts)
