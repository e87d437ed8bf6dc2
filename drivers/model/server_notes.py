"""The lines a server of the emulated arm writes to its client between frames; no I/O.

``armbench emulate`` tells a client things the serial line itself cannot: that another client has
the arm (``busy``), that it was disconnected, that bytes it sent were dropped because the
receive buffer was full (``overrun``). Each is one line ``\\r\\narmbench emulate: TEXT\\r\\n``
between reply frames, without ``$`` or ``#``, so a framer takes it for noise; :class:`ServerNotes`
picks them out of the byte stream the driver reads, so the driver can show them.
"""

from __future__ import annotations

from typing import Final

__all__ = ["NOTE_PREFIX", "ServerNotes", "note_line"]

NOTE_PREFIX: Final = b"armbench emulate: "
#: Longest note text kept; a longer line is cut (a peer cannot grow the buffer).
MAX_NOTE_BYTES: Final = 400


def note_line(text: str) -> bytes:
    """``text`` as a server writes it: on a line of its own, without the frame delimiters."""
    clean = text.replace("$", "?").replace("#", "?").replace("\r", " ").replace("\n", " ")
    return b"\r\n" + NOTE_PREFIX + clean.encode("ascii", "replace") + b"\r\n"


class ServerNotes:
    """Finds server notes in chunks of a byte stream, also when a note is split across chunks."""

    __slots__ = ("_partial",)

    def __init__(self) -> None:
        self._partial = b""

    def feed(self, data: bytes) -> list[str]:
        """The texts of the notes ``data`` completes, in stream order."""
        buf = self._partial + data if self._partial else data
        self._partial = b""
        notes: list[str] = []
        start = 0
        while (i := buf.find(NOTE_PREFIX, start)) >= 0:
            text_at = i + len(NOTE_PREFIX)
            end = buf.find(b"\n", text_at)
            if end < 0:
                if len(buf) - text_at > MAX_NOTE_BYTES:  # no end in sight: cut it here
                    notes.append(_text(buf[text_at:text_at + MAX_NOTE_BYTES]))
                else:
                    self._partial = buf[i:]
                return notes
            notes.append(_text(buf[text_at:min(end, text_at + MAX_NOTE_BYTES)]))
            start = end + 1
        if buf and buf[-1] in NOTE_PREFIX:  # keep what may be the start of a prefix
            for k in range(min(len(NOTE_PREFIX) - 1, len(buf) - start), 0, -1):
                if NOTE_PREFIX.startswith(buf[-k:]):
                    self._partial = buf[-k:]
                    break
        return notes


def _text(raw: bytes) -> str:
    return raw.rstrip(b"\r").decode("ascii", "replace")
