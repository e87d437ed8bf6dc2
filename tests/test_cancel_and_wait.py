"""``cancel_and_wait``: a helper task stopped without losing the caller's own cancellation (a
Ctrl-C that cancels the run's main task while it stops a recorder must still end the run)."""

from __future__ import annotations

import asyncio

import pytest

from armbench.drivers.model.tasks import cancel_and_wait
from armbench.fakes.clock.vclock import run_virtual


async def _slow_to_stop(stopped: list[str]) -> None:
    """A helper that takes a while to finish once cancelled (as a recorder's last sample)."""
    try:
        await asyncio.sleep(10.0)
    except asyncio.CancelledError:
        await asyncio.sleep(0.5)
        stopped.append("helper")
        raise


def test_the_helpers_cancellation_ends_there() -> None:
    async def main() -> list[str]:
        stopped: list[str] = []
        helper = asyncio.create_task(_slow_to_stop(stopped))
        await asyncio.sleep(0.1)
        await cancel_and_wait(helper)
        return stopped
    assert run_virtual(main()) == ["helper"]


def test_the_callers_cancellation_goes_on() -> None:
    """Cancelled while it waits for the helper: the caller is cancelled (with a plain
    ``suppress(CancelledError)`` around the await it would have gone on), and the helper, whose
    wait the cancellation reaches too, is finished."""
    async def main() -> tuple[list[str], bool]:
        stopped: list[str] = []
        helper = asyncio.create_task(_slow_to_stop(stopped))

        async def caller() -> str:
            await asyncio.sleep(0.1)
            await cancel_and_wait(helper)
            return "went on"

        task = asyncio.create_task(caller())
        await asyncio.sleep(0.2)  # the caller waits for the helper now
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        return stopped, helper.done()
    assert run_virtual(main()) == ([], True)


def test_another_error_of_the_helper_is_raised() -> None:
    async def main() -> None:
        async def fails_on_cancel() -> None:
            try:
                await asyncio.sleep(10.0)
            except asyncio.CancelledError:
                raise OSError("port gone") from None
        helper = asyncio.create_task(fails_on_cancel())
        await asyncio.sleep(0.1)
        await cancel_and_wait(helper)
    with pytest.raises(OSError, match="port gone"):
        run_virtual(main())
