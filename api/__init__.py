"""armbench: a hardware-in-the-loop test bench for the Igus RoboLink 4-DoF arm and its firmware.

The public API: :class:`Arm` and :func:`connect` (the asyncio driver) with its
:class:`LinkOptions`, the typed errors and the version. The driver's names load on first use, so
that importing the emulator (``armbench.fakes``) never imports the driver.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from armbench.drivers.model.errors import (
    ArmbenchError,
    DriverClosedError,
    DriverError,
    FrameValueError,
    InvalidTargetError,
    JointRangeError,
    MoveInterruptedError,
    MoveTimeoutError,
    PortLostError,
    ProtocolError,
    ReplyTimeoutError,
    TransportError,
    WaitTimeoutError,
)
from armbench.drivers.model.lazy_names import lazy_name

if TYPE_CHECKING:
    from armbench.drivers.host.arm import Arm, LinkOptions, PathRun, ReconnectPolicy
    from armbench.drivers.host.state import JointState
    from armbench.drivers.model.settings import RobotSettings

__version__ = "0.1.0"

__all__ = [
    "Arm",
    "ArmbenchError",
    "DriverClosedError",
    "DriverError",
    "FrameValueError",
    "InvalidTargetError",
    "JointRangeError",
    "JointState",
    "LinkOptions",
    "MoveInterruptedError",
    "MoveTimeoutError",
    "PathRun",
    "PortLostError",
    "ProtocolError",
    "ReconnectPolicy",
    "ReplyTimeoutError",
    "RobotSettings",
    "TransportError",
    "WaitTimeoutError",
    "__version__",
    "connect",
]

_LAZY = {
    "Arm": "armbench.drivers.host.arm",
    "LinkOptions": "armbench.drivers.host.arm",
    "PathRun": "armbench.drivers.host.arm",
    "ReconnectPolicy": "armbench.drivers.host.arm",
    "connect": "armbench.drivers.host.arm",
    "RobotSettings": "armbench.drivers.model.settings",
    "JointState": "armbench.drivers.host.state",
}


def __getattr__(name: str) -> object:
    return lazy_name(__name__, _LAZY, name)
