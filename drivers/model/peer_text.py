"""What a peer sent, shortened before it is echoed: in an error, a log line, a status or an event.

A peer (a ROS 2 client, a labgrid coordinator, a server on the line) may send a string of any
length: a 10 MB joint name would otherwise be copied whole into the rejection the node publishes,
its event and its log line. Every echo of peer text goes through :func:`peer_repr` (a value as a
message quotes it, ``repr``) or :func:`peer_str` (plain text), which keep the first
:data:`MAX_ECHO_CHARS` characters and say how many were cut. Imports nothing of armbench.
"""

from __future__ import annotations

from typing import Final

__all__ = ["MAX_ECHO_CHARS", "peer_repr", "peer_str"]

#: Characters of a peer's text kept in an echo; the rest is replaced by a count.
MAX_ECHO_CHARS: Final = 200


def peer_str(text: str, limit: int = MAX_ECHO_CHARS) -> str:
    """``text`` cut to ``limit`` characters, followed by ``…(N characters)`` (its whole length)
    when it is longer."""
    return text if len(text) <= limit else f"{text[:limit]}…({len(text)} characters)"


def peer_repr(value: object, limit: int = MAX_ECHO_CHARS) -> str:
    """``value`` quoted as a message quotes it (``repr``), at most about ``limit`` characters: a
    long string is cut as :func:`peer_str` cuts it, a list or tuple shows its first items and
    how many it has. Nothing of the value beyond the limit is copied or formatted."""
    if isinstance(value, str):
        if len(value) <= limit:
            return repr(value)
        return f"{value[:limit]!r}…({len(value)} characters)"
    if isinstance(value, list | tuple):
        parts: list[str] = []
        used = 0
        for item in value:
            if used >= limit:
                break
            parts.append(peer_repr(item, limit - used))
            used += len(parts[-1]) + 2
        more = "" if len(parts) == len(value) else f", …({len(value)} items)"
        text = ", ".join(parts) + more
        return f"[{text}]" if isinstance(value, list) else f"({text})"
    return peer_str(repr(value), limit)
