"""Helpers of the tests that use real sockets: a free loopback port, and whether one listens."""

from __future__ import annotations

import socket


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def listening(tcp_port: int) -> bool:
    """True when something listens on ``tcp_port`` over IPv4 or IPv6 (gRPC's servers listen on
    IPv6 sockets that take IPv4 too), read from /proc with no connection: a probe connection
    would make ser2net open the serial device."""
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            with open(table) as fh:
                rows = fh.readlines()[1:]
        except FileNotFoundError:  # no IPv6 in this kernel
            continue
        for line in rows:
            fields = line.split()
            if fields[1].endswith(f":{tcp_port:04X}") and fields[3] == "0A":
                return True
    return False
