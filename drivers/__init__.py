"""Host side of armbench: the protocol codec, the robot model, kinematics and the asyncio driver."""

from drivers.errors import ArmbenchError
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
    "ArmbenchError",
    "Command",
    "FrameError",
    "FrameValueError",
    "Framer",
    "Geometry",
    "JointSettings",
    "ProtocolError",
    "Reply",
    "RobotSettings",
    "SerialSettings",
    "SettingsError",
    "load_settings",
    "rad_to_ticks",
    "ticks_to_rad",
]
