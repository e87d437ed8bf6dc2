"""Stopping a helper task without losing the caller's own cancellation.

``task.cancel()`` then ``with suppress(CancelledError): await task`` takes a cancellation of the
*caller* (Ctrl-C cancelling the run's main task while it waits there) for the helper's, and the
run goes on as if nothing had been asked. :func:`cancel_and_wait` passes the caller's on.
"""

from __future__ import annotations

import asyncio
from typing import Any

__all__ = ["cancel_and_wait"]


async def cancel_and_wait(task: asyncio.Future[Any]) -> None:
    """Cancel ``task`` and wait until it has finished. Its own ``CancelledError`` ends here; one
    of the calling task (cancelled while it waits, or already being cancelled) goes on up. Any
    other exception of ``task`` is raised."""
    task.cancel()
    try:
        await task
    except asyncio.CancelledError:
        current = asyncio.current_task()
        if current is not None and current.cancelling():
            raise
