"""How a connection to the arm behaves: :class:`LinkOptions`, which
:class:`~armbench.drivers.host.link.ArmLink` and ``Arm.connect`` take (or its fields by
keyword), and the defaults of its times."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path as FsPath
from typing import Final

from armbench.drivers.capture.jsonl import CaptureWriter
from armbench.drivers.host.link_outages import ReconnectPolicy
from armbench.drivers.model.bounds import Bound, check, option_refused
from armbench.drivers.transports import Transport

__all__ = ["CONNECT_TIMEOUT_S", "DEFAULT_LINK_OPTIONS", "RESEND_AFTER_S", "LinkOptions"]

#: While waiting for arrival, the command is sent again when the distance to go has not shrunk
#: for this long (a command lost or corrupted on the line, an emulator restarted).
RESEND_AFTER_S: Final = 0.3
#: How long ``connect`` waits for the first valid reply (an Arduino resets when the port opens
#: and its boot loader takes up to ~2 s before the firmware replies).
CONNECT_TIMEOUT_S: Final = 3.0
#: The times of a connection (s) and the factor on its move timeouts: finite and above 0.
_POSITIVE: Final = Bound(0.0, low_open=True)


@dataclass(frozen=True, slots=True)
class LinkOptions:
    """How a connection to the arm behaves: :class:`~armbench.drivers.host.link.ArmLink` and
    ``Arm.connect`` take one, or any of its fields by keyword. Each time is checked when the
    options are made (:class:`~armbench.drivers.model.errors.InvalidTargetError` naming it)."""

    reply_timeout_s: float = 0.5
    """Longest silence tolerated while waiting for replies."""
    capture: str | FsPath | CaptureWriter | None = None
    """A JSON Lines file that receives every frame in and out
    (:mod:`armbench.drivers.capture.jsonl`), times counted from the opening; or a
    :class:`~armbench.drivers.capture.jsonl.CaptureWriter` with a time origin of the caller's,
    which the connection uses and closes."""
    reconnect: bool | ReconnectPolicy = False
    """True or a :class:`ReconnectPolicy`: reopen a lost port with back-off."""
    connect_timeout_s: float = CONNECT_TIMEOUT_S
    """Wait for the first valid reply."""
    resend_after_s: float = RESEND_AFTER_S
    """Resend a move's command when the distance to go has not shrunk for this long."""
    transport: Transport | None = None
    """An unopened transport to use instead of ``open_transport(port)`` (reconnections still use
    ``open_transport``)."""
    move_timeout_scale: float = 1.0
    """Factor on every default move and path timeout, for an arm that moves slower than law (12)
    says (a heavy payload, an emulator on a starved machine)."""

    def __post_init__(self) -> None:
        for name in ("reply_timeout_s", "connect_timeout_s", "resend_after_s",
                     "move_timeout_scale"):
            object.__setattr__(self, name, check(name, getattr(self, name), _POSITIVE,
                                                 option_refused))


#: The options of a connection given none.
DEFAULT_LINK_OPTIONS: Final = LinkOptions()
