"""A ROS client process for the tests: takes ``/tf_static`` (latched), ``/tf`` and
``/joint_states`` until ``COUNT`` joint states have a ``/tf`` of the same stamp, and prints them as
JSON: ``{"static": [[parent, child, pose]...], "pairs": [{"q": [...], "velocity": [...],
"tf": [[parent, child, pose]...]}...]}`` with each pose ``[tx, ty, tz, qx, qy, qz, qw]``.

``python tests/ros2_tf_listener.py COUNT TIMEOUT_S`` (the message support from the cache the
environment's ``XDG_CACHE_HOME`` names).
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any


def _transforms(msg: Any) -> list[list[Any]]:
    out = []
    for t in msg.transforms:
        tr, r = t.transform.translation, t.transform.rotation
        out.append([t.header.frame_id, t.child_frame_id, [tr.x, tr.y, tr.z, r.x, r.y, r.z, r.w]])
    return out


def main(count: int, timeout_s: float) -> int:
    from armbench.frontends.ros2_node.msgs_build import ensure_messages

    ensure_messages(build=False)
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile
    from sensor_msgs.msg import JointState
    from tf2_msgs.msg import TFMessage

    rclpy.init()
    node = rclpy.create_node("armbench_tf_listener")
    static: list[list[Any]] = []
    tfs: dict[tuple[int, int], list[list[Any]]] = {}
    states: dict[tuple[int, int], tuple[list[float], list[float]]] = {}

    def stamp(msg: Any) -> tuple[int, int]:
        return int(msg.header.stamp.sec), int(msg.header.stamp.nanosec)

    every = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL)
    node.create_subscription(TFMessage, "tf_static", lambda m: static.extend(_transforms(m)),
                             QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    node.create_subscription(TFMessage, "tf",
                             lambda m: tfs.setdefault(stamp(m.transforms[0]), _transforms(m)),
                             every)
    node.create_subscription(JointState, "joint_states",
                             lambda m: states.setdefault(stamp(m), (list(m.position),
                                                                    list(m.velocity))), every)
    deadline = time.monotonic() + timeout_s
    while not (static and len(set(tfs) & set(states)) >= count):
        if time.monotonic() > deadline:
            print(json.dumps({"error": f"timed out: {len(static)} static, {len(tfs)} tf, "
                                       f"{len(states)} joint states"}))
            return 1
        rclpy.spin_once(node, timeout_sec=0.05)
    both = sorted(set(tfs) & set(states))[:count]
    print(json.dumps({"static": static, "pairs": [
        {"q": states[k][0], "velocity": states[k][1], "tf": tfs[k]} for k in both]}))
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]), float(sys.argv[2])))
