"""The node's ROS 2 names: its topics, and the rules its node name and namespace follow.

The rules are rcl's (letters, digits and ``_``, not starting with a digit; lengths such that every
topic of the node stays a valid name), checked here without ROS so that a bad ``--node-name`` or
``--namespace`` is one line before anything starts, not an rclpy traceback once the arm is open.
"""

from __future__ import annotations

import re
from typing import Final

__all__ = ["MAX_NAMESPACE", "MAX_NODE_NAME", "TOPICS", "namespace_problem", "node_name_problem"]

#: Every topic of the node by its role: relative names, so they resolve under the node's
#: namespace (``/`` by default: ``/joint_states``); ``/clock`` is the graph's, absolute. The
#: arm's state and commands have the names of the MCAP capture's channels
#: (:mod:`armbench.drivers.capture.mcap_writer`).
TOPICS: Final = {
    "joint_states": "joint_states",
    "tf": "tf",
    "tf_static": "tf_static",
    "robot_description": "robot_description",
    "commanded": "joint_states_goal",
    "trajectory": "armbench/joint_trajectory",
    "status": "armbench/trajectory_status",
    "events": "armbench/events",
    "clock": "/clock",
}
#: rcl's longest node name.
MAX_NODE_NAME: Final = 255
#: rcl's longest fully qualified topic name with Fast DDS.
_MAX_TOPIC_NAME: Final = 247
#: The longest namespace: the node's longest topic under it is still a valid topic name.
MAX_NAMESPACE: Final = _MAX_TOPIC_NAME - 1 - max(len(t) for t in TOPICS.values()
                                                 if not t.startswith("/"))
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def node_name_problem(name: str) -> str | None:
    """Why ``name`` cannot be the node's name, or None when it can."""
    if len(name) <= MAX_NODE_NAME and _TOKEN.fullmatch(name):
        return None
    return (f"must be a ROS node name: 1..{MAX_NODE_NAME} letters, digits and _, not starting "
            "with a digit")


def namespace_problem(namespace: str) -> str | None:
    """Why ``namespace`` cannot be the node's namespace, or None when it can ("" and "/" are the
    root)."""
    first, *tokens = namespace.split("/")
    if namespace in ("", "/") or (len(namespace) <= MAX_NAMESPACE and first == "" and tokens
                         and all(_TOKEN.fullmatch(t) for t in tokens)):
        return None
    return (f"must be /name[/name...], each name letters, digits and _, not starting with a "
            f"digit, at most {MAX_NAMESPACE} characters in all")
