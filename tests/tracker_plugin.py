"""A ``--tracker`` plug-in (a ``PoseSource``, ``bench/runner/truth.py``) for the tracker of
``foreign_arms/tracker_arm.py``: the newest line of its stream as the true TCP and joints.

``--tracker tracker_plugin:TrackerArmSource`` (with ``tests/`` on ``PYTHONPATH``); the stream's
address comes from ``$ARMBENCH_TRACKER`` (``HOST:PORT``), since ``calibrate`` passes the plug-in
no parameters."""

from __future__ import annotations

import os

from foreign_arms.tracker_client import TrackerStream


class TrackerArmSource:
    """The tracker stream as a pose source: opened and closed around the procedure."""

    def __init__(self, address: str | None = None) -> None:
        where = address or os.environ.get("ARMBENCH_TRACKER", "")
        host, sep, port = where.rpartition(":")
        if not sep or not port.isdigit():
            raise ValueError(f"tracker address {where!r} is not HOST:PORT "
                             "(set $ARMBENCH_TRACKER)")
        self._stream = TrackerStream(host, int(port))

    async def open(self) -> None:
        """Connect and wait for the first line."""
        await self._stream.__aenter__()

    async def close(self) -> None:
        """Stop reading and disconnect."""
        await self._stream.__aexit__(None, None, None)

    def true_position_m(self) -> tuple[float, float, float] | None:
        """The newest true TCP (m, base frame)."""
        if not self._stream.samples:
            return None
        s = self._stream.samples[-1]
        return s[1], s[2], s[3]

    def true_joints_rad(self) -> tuple[float, ...] | None:
        """The newest true link angles (rad, protocol convention)."""
        if not self._stream.samples:
            return None
        return tuple(self._stream.samples[-1][4:8])
