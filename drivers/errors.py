"""The root of armbench's typed errors, so a front end can tell user errors from bugs."""

from __future__ import annotations

__all__ = ["ArmbenchError", "PortLostError", "TransportError"]


class ArmbenchError(Exception):
    """Base of every error armbench raises on purpose (bad input, lost port, timeout, ...)."""


class TransportError(ArmbenchError, OSError):
    """A transport could not be opened, configured or used; names the port."""

    def __init__(self, port: str, reason: str) -> None:
        super().__init__(f"{port}: {reason}")
        self.port = port
        self.reason = reason


class PortLostError(TransportError):
    """The port went away while open (USB unplugged, TCP reset, pty closed, emulator killed)."""
