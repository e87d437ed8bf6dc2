"""The arm runs one trajectory at a time, whichever way it came in (the action or the topic).

A job is an asyncio task on the loop. Starting one replaces the one running: that one is
cancelled with a reason and waited for (it holds the arm on its way out, as the driver's streaming
does when cancelled), so each job learns why it ended from :meth:`OneJob.reason`.
"""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine
from typing import Any

__all__ = ["OneJob"]


class OneJob:
    """The slot of the running job; a cancelled job's reason is ``(state, text)``: ``state``
    ``preempted`` (a newer trajectory), ``canceled`` (its client asked) or ``aborted`` (the
    node: shutdown, a silent arm, a lost link)."""

    def __init__(self) -> None:
        self.task: asyncio.Task[Any] | None = None
        self._reasons: dict[asyncio.Task[Any], tuple[str, str]] = {}

    @property
    def running(self) -> bool:
        """Whether a job is under way."""
        return self.task is not None and not self.task.done()

    def cancel(self, state: str, text: str, task: asyncio.Task[Any] | None = None) -> None:
        """Cancel ``task`` (default: the running job) with this reason; no wait."""
        task = task or self.task
        if task is not None and not task.done():
            self._reasons.setdefault(task, (state, text))
            task.cancel()

    async def replace(self, by: str) -> None:
        """Cancel the running job (``preempted``: replaced by ``by``) and wait for it to end."""
        task = self.task
        if task is not None and not task.done():
            self.cancel("preempted", f"replaced by {by}", task)
            await asyncio.wait({task})

    def start(self, coro: Coroutine[Any, Any, Any]) -> asyncio.Task[Any]:
        """Run ``coro`` as the job (after :meth:`replace`)."""
        self.task = asyncio.ensure_future(coro)
        return self.task

    def reason(self, task: asyncio.Task[Any]) -> tuple[str, str]:
        """Why ``task`` was cancelled (forgotten once asked)."""
        return self._reasons.pop(task, ("aborted", "cancelled"))
