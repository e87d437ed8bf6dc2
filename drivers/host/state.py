"""What the driver reports: one reply of the arm as a joint state, and the emulator's ground truth
beside it."""

from __future__ import annotations

from typing import NamedTuple, Protocol

from armbench.drivers.model.kinematics import Vec4, tcp_position
from armbench.drivers.model.settings import RobotSettings

__all__ = ["GroundTruth", "JointState"]


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


class GroundTruth(Protocol):
    """What an emulator reports beside each reply (``armbench.fakes.firmware.boards.TruthSample``):
    the real joint
    angles (``true_rad``) and the firmware's belief (``firmware_rad``) at ``t_s``."""

    @property
    def t_s(self) -> float: ...

    @property
    def true_rad(self) -> tuple[float, float, float, float]: ...

    @property
    def firmware_rad(self) -> tuple[float, float, float, float]: ...
