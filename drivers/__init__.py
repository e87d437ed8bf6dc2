"""Host side of armbench: the protocol codec, the robot model, kinematics and the asyncio driver.

The driver (``drivers.arm``) is imported lazily on first use of its names, so that the emulator,
which shares the codec and the robot model, never imports the driver.
"""

from drivers.errors import ArmbenchError, PortLostError, TransportError
from drivers.kinematics import (
    BRANCHES,
    IKSolution,
    JointLimitError,
    KinematicsError,
    LimitViolation,
    UnreachableError,
    dh_parameters,
    dh_to_protocol,
    fk,
    fk_dh,
    ik,
    ik_best,
    protocol_to_dh,
    tcp_position,
    wrap_protocol,
)
from drivers.protocol import (
    Command,
    FrameError,
    Framer,
    FrameValueError,
    ProtocolError,
    Reply,
    rad_to_ticks,
    ticks_to_rad,
)
from drivers.settings import (
    Geometry,
    JointSettings,
    RobotSettings,
    SerialSettings,
    SettingsError,
    load_settings,
)

__all__ = [
    "BRANCHES",
    "ArmbenchError",
    "Command",
    "FrameError",
    "FrameValueError",
    "Framer",
    "Geometry",
    "IKSolution",
    "JointLimitError",
    "JointSettings",
    "KinematicsError",
    "LimitViolation",
    "PortLostError",
    "ProtocolError",
    "Reply",
    "RobotSettings",
    "SerialSettings",
    "SettingsError",
    "TransportError",
    "UnreachableError",
    "dh_parameters",
    "dh_to_protocol",
    "fk",
    "fk_dh",
    "ik",
    "ik_best",
    "load_settings",
    "protocol_to_dh",
    "rad_to_ticks",
    "tcp_position",
    "ticks_to_rad",
    "wrap_protocol",
]

_DRIVER_NAMES = ("Arm", "JointState", "PathRun", "ReconnectPolicy", "DriverError",
                 "DriverClosedError", "ReplyTimeoutError", "WaitTimeoutError", "MoveTimeoutError",
                 "MoveInterruptedError", "InvalidTargetError", "JointRangeError")
__all__ += list(_DRIVER_NAMES)


def __getattr__(name: str) -> object:
    if name in _DRIVER_NAMES:
        from drivers import arm

        return getattr(arm, name)
    raise AttributeError(f"module 'drivers' has no attribute {name!r}")
