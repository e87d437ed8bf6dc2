"""Host side of armbench: the protocol codec, the robot model, kinematics and the asyncio driver.

The driver (``drivers.arm``) is imported lazily on first use of its names, so that the emulator,
which shares the codec and the robot model, never imports the driver. Before anything else the
package chooses the build of its hot modules (``drivers.compiled``): compiled, or their source.
"""

from drivers.compiled import build

build()


from drivers.errors import (
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
from drivers.state import JointState

__all__ = [
    "BRANCHES",
    "ArmbenchError",
    "Command",
    "DriverClosedError",
    "DriverError",
    "FrameError",
    "FrameValueError",
    "Framer",
    "Geometry",
    "IKSolution",
    "InvalidTargetError",
    "JointLimitError",
    "JointRangeError",
    "JointSettings",
    "JointState",
    "KinematicsError",
    "LimitViolation",
    "MoveInterruptedError",
    "MoveTimeoutError",
    "PortLostError",
    "ProtocolError",
    "Reply",
    "ReplyTimeoutError",
    "RobotSettings",
    "SerialSettings",
    "SettingsError",
    "TransportError",
    "UnreachableError",
    "WaitTimeoutError",
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

_DRIVER_NAMES = ("Arm", "PathRun", "ReconnectPolicy")
__all__ += list(_DRIVER_NAMES)


def __getattr__(name: str) -> object:
    if name in _DRIVER_NAMES:
        from drivers import arm

        return getattr(arm, name)
    raise AttributeError(f"module 'drivers' has no attribute {name!r}")
