"""The parts of a port URL a transport reads, and the refusal of every other one: a path after
``socket://HOST:PORT``, a fragment, a user name, an address where none is read. A part no
transport reads is refused naming it, never ignored: a mistyped port must fail as bad input, not
reach another arm or wait for one that is not there.
"""

from __future__ import annotations

from urllib.parse import SplitResult, urlsplit

from armbench.drivers.model.errors import TransportError, shown_port

__all__ = ["PART_CHARS", "split_port"]

#: The most characters of a refused part an error shows (the port itself is shown too).
PART_CHARS = 80


def split_port(port: str, form: str, *, address: bool, query: bool,
               path: bool = False) -> SplitResult:
    """``urlsplit(port)``, refused (a :class:`TransportError` naming the part) when it holds a
    part the transport does not read. ``form`` says what the transport reads (``"socket://HOST:
    PORT"``); ``address``: it reads ``HOST:PORT`` or a name after ``//`` (and no user name),
    else nothing may stand there; ``query``: it reads a query (and checks its keys itself);
    ``path``: it reads a path. A lone ``/`` is no path."""
    try:
        parts = urlsplit(port)
    except ValueError as exc:
        raise TransportError(port, f"is not {form} ({exc})") from None
    refused = [("fragment", parts.fragment)]
    if not path:
        refused.insert(0, ("path", "" if parts.path == "/" else parts.path))
    if not query:
        refused.insert(1, ("query", parts.query))
    if address:
        refused.insert(0, ("user name", parts.netloc.rpartition("@")[0]))
    else:
        refused.insert(0, ("address", parts.netloc))
    for name, value in refused:
        if value:
            shown = shown_port(value, PART_CHARS)
            raise TransportError(port, f"the {name} {shown!r} is not understood ({form} takes "
                                       "none)")
    return parts
