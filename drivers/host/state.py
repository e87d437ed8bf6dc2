"""What the driver reports: one reply of the arm as a joint state."""

from __future__ import annotations

from typing import NamedTuple

from armbench.drivers.model.kinematics import Vec4, tcp_position
from armbench.drivers.model.settings import RobotSettings

__all__ = ["JointState"]


class JointState(NamedTuple):
    """One reply of the arm.

    ``t_s``: loop time of its arrival (seconds); ``q_rad``: joint angles in the protocol
    convention, each mapped into its joint's window (so negative angles come back negative);
    ``ticks``: the raw wire values; ``seq``: its number since the driver connected (1, 2, ...),
    so a consumer can tell how many replies it has not seen.
    """

    t_s: float
    q_rad: Vec4
    ticks: tuple[int, int, int, int]
    seq: int

    def tcp_m(self, settings: RobotSettings) -> tuple[float, float, float]:
        """TCP position (m, base frame) by forward kinematics."""
        p = tcp_position(self.q_rad, settings)
        return float(p[0]), float(p[1]), float(p[2])
