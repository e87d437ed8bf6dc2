"""The arm as a URDF from the DH table and the robot settings, for RViz and Foxglove's 3D panel.

The kinematic tree is the standard-DH chain of :mod:`armbench.drivers.model.kinematics`: joint
``j{i}`` (revolute, axis ``±z`` by the joint's ``sign``, origin turned by its ``offset_rad``) turns
frame ``link{i}_root`` in its parent (``base_link`` or ``link{i-1}``); DH frame ``i`` is the link
``link{i}``, fixed to the root by ``Tz(d_i)·Tx(a_i)·Rx(α_i)``. So a joint position is the
protocol angle the driver reports (``JointState`` of ``/joint_states``) and the origin of
``link4`` is the TCP. Joint limits are the settings' (protocol convention); the velocity and
effort limits URDF requires are nominal (the firmware does not state them). Geometry is simple:
a box for the base, cylinders along each DH offset.
"""

from __future__ import annotations

import math
from xml.sax.saxutils import quoteattr

from armbench.drivers.model.kinematics import dh_parameters
from armbench.drivers.model.ros2 import link_names
from armbench.drivers.model.settings import RobotSettings

__all__ = ["LINK_RADIUS_M", "NOMINAL_EFFORT_NM", "NOMINAL_VELOCITY_RAD_S", "robot_urdf"]

#: Radius of the cylinders drawn along the DH offsets (m).
LINK_RADIUS_M = 0.03
#: The ``velocity`` limit written for every joint (rad/s): nominal, for tools that need one.
NOMINAL_VELOCITY_RAD_S = 1.0
#: The ``effort`` limit written for every joint (N·m): nominal, for tools that need one.
NOMINAL_EFFORT_NM = 10.0

_COLOURS = {"base": "0.3 0.3 0.3 1", "link": "0.95 0.55 0.1 1"}


def _num(x: float) -> str:
    return repr(float(x))


def _origin(xyz: tuple[float, float, float], rpy: tuple[float, float, float]) -> str:
    return (f'<origin xyz="{" ".join(_num(v) for v in xyz)}" '
            f'rpy="{" ".join(_num(v) for v in rpy)}"/>')


def _cylinder(length_m: float, xyz: tuple[float, float, float],
              rpy: tuple[float, float, float]) -> str:
    return (f"    <visual>{_origin(xyz, rpy)}<geometry><cylinder radius=\"{_num(LINK_RADIUS_M)}\" "
            f"length=\"{_num(length_m)}\"/></geometry><material name=\"link\"/></visual>\n")


def _link_visuals(a_m: float, d_m: float) -> str:
    """Cylinders from ``link{i}_root`` along ``d`` (its z axis) then ``a`` (its x axis)."""
    out = ""
    if abs(d_m) > 1e-9:
        out += _cylinder(abs(d_m), (0.0, 0.0, d_m / 2), (0.0, 0.0, 0.0))
    if abs(a_m) > 1e-9:
        out += _cylinder(abs(a_m), (a_m / 2, 0.0, d_m), (0.0, math.pi / 2, 0.0))
    return out


def robot_urdf(settings: RobotSettings, name: str = "robolink") -> str:
    """The URDF text of the arm described by ``settings``."""
    table = dh_parameters(settings.geometry)
    parts = [f'<?xml version="1.0"?>\n<robot name={quoteattr(name)}>\n']
    parts += [f'  <material name="{k}"><color rgba="{v}"/></material>\n'
              for k, v in _COLOURS.items()]
    base = 0.12
    parts.append(f'  <link name="base_link">\n    <visual>{_origin((0, 0, base / 4), (0, 0, 0))}'
                 f'<geometry><box size="{base} {base} {base / 2}"/></geometry>'
                 '<material name="base"/></visual>\n  </link>\n')
    for i, (joint, (a, alpha, d)) in enumerate(zip(settings.joints, table, strict=True), 1):
        parent, root, link = link_names(i)
        lower, upper = joint.lower_rad, joint.upper_rad
        parts.append(
            f'  <joint name={quoteattr(joint.name)} type="revolute">\n'
            f'    <parent link="{parent}"/><child link="{root}"/>\n'
            f'    {_origin((0.0, 0.0, 0.0), (0.0, 0.0, joint.offset_rad))}\n'
            f'    <axis xyz="0 0 {joint.sign}"/>\n'
            f'    <limit lower="{_num(lower)}" upper="{_num(upper)}" '
            f'effort="{_num(NOMINAL_EFFORT_NM)}" velocity="{_num(NOMINAL_VELOCITY_RAD_S)}"/>\n'
            f'  </joint>\n'
            f'  <link name="{root}">\n{_link_visuals(float(a), float(d))}  </link>\n'
            f'  <joint name="{link}_fixed" type="fixed">\n'
            f'    <parent link="{root}"/><child link="{link}"/>\n'
            f'    {_origin((float(a), 0.0, float(d)), (float(alpha), 0.0, 0.0))}\n'
            f'  </joint>\n'
            f'  <link name="{link}"/>\n')
    parts.append("</robot>\n")
    return "".join(parts)
