"""Helpers of the tests that use real sockets: a free loopback port, and whether one listens."""

from __future__ import annotations

import socket


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def listening(tcp_port: int) -> bool:
    """True when something listens on 127.0.0.1:``tcp_port`` (read from /proc, no connection:
    a probe connection would make ser2net open the serial device)."""
    with open("/proc/net/tcp") as fh:
        for line in fh.readlines()[1:]:
            fields = line.split()
            if fields[1].endswith(f":{tcp_port:04X}") and fields[3] == "0A":
                return True
    return False
