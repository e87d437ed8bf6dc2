"""The arm on a ROS 2 graph: a node driving any port armbench speaks (``armbench ros2``).

:mod:`.trajectory` checks and plans a ``JointTrajectory`` (no ROS needed), :mod:`.node` is the
node (rclpy on a thread of its own beside the asyncio loop of the driver), :mod:`.client` a ROS
client run as a separate process (the accuracy square sent as a trajectory, a ``/joint_states``
listener), :mod:`.square` the comparison of the square through ROS with the driver's own
coordinated run. rclpy and the message packages come from the extra ``armbench[ros2]``
(``docs/ros.md``); :func:`require_rclpy` says so when they are missing.
"""

from __future__ import annotations

import importlib.util

from armbench.drivers.model.errors import ArmbenchError

__all__ = ["ROS2_MODULES", "Ros2UnavailableError", "missing_ros2", "require_rclpy"]

#: The Python modules of the extra the node imports.
ROS2_MODULES = ("rclpy", "sensor_msgs", "std_msgs", "trajectory_msgs", "rosgraph_msgs",
                "builtin_interfaces")


class Ros2UnavailableError(ArmbenchError):
    """rclpy or a message package of the extra ``armbench[ros2]`` cannot be imported."""


def missing_ros2() -> str | None:
    """Why the ROS 2 extra is unusable here (the first module missing), or None if it is."""
    for name in ROS2_MODULES:
        if importlib.util.find_spec(name) is None:
            return (f"the Python module {name!r} is not installed: "
                    "pip install 'armbench[ros2]' (docs/ros.md)")
    return None


def require_rclpy() -> None:
    """Raise :class:`Ros2UnavailableError` (one line on the CLI) when the extra is missing, or
    when rclpy is installed but its shared libraries cannot be loaded."""
    why = missing_ros2()
    if why is not None:
        raise Ros2UnavailableError(why)
    try:
        import rclpy  # noqa: F401  (loads the C extension and the rmw libraries)
    except ImportError as exc:
        raise Ros2UnavailableError(
            f"rclpy is installed but does not load ({exc}); the ROS wheels set LD_LIBRARY_PATH "
            "by re-executing Python at start-up (ros_wheels_bootstrapper.pth): run Python "
            "without -S / -I, or set LD_LIBRARY_PATH as docs/ros.md says") from exc
