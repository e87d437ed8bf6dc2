"""Before a run on an arm that is already there makes its folder: the arm answers at the port.

A target that starts a fresh arm per trial (``fake://``, ``avr://`` on virtual time) has no arm
to find. Any other (a serial device, ``socket://``, ``rfc2217://``, ``labgrid://``, ``avr://`` in
real time) is opened as the run opens it, must give a valid reply frame within ``[bench]
connect_timeout_s``, and is closed again. A port that cannot be opened or answers nothing before
the first trial is bad input (:class:`NoArmError`, exit 2: a mistyped port must not be retried
by CI), reported before the run folder exists (a resumed run's folder is left as it was). A link
lost once the run has begun makes the run incomplete (exit 4, the record kept). The classes per
transport: ``docs/ci.md``. ``armbench perf --port`` asks the same before it measures.
"""

from __future__ import annotations

import asyncio
from collections.abc import Sequence

from armbench.bench.runner.options import BenchPlan
from armbench.drivers.model.errors import (
    ArmbenchError,
    PortLostError,
    ReplyTimeoutError,
    TransportError,
)
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.transports.target import Target

__all__ = ["NoArmError", "find_arm", "needs_probe", "probe_arm", "probe_arms", "probe_arms_sync"]


class NoArmError(TransportError):
    """No arm could be reached at the port before the first trial: the port could not be
    opened, closed at once, or gave no valid reply within the connect timeout. Bad input."""


def needs_probe(target: Target) -> bool:
    """Whether work on ``target`` talks to an arm that is already there (not one it starts)."""
    return not target.capabilities.fresh_per_trial


def _why(exc: BaseException, connect_timeout_s: float) -> str:
    """What went wrong at the port, and what to check."""
    if isinstance(exc, ReplyTimeoutError):
        return (f"it opened, but no valid reply frame came within {connect_timeout_s:g} s "
                "([bench] connect_timeout_s): is the arm on, and is this its port and baud "
                "rate?")
    if isinstance(exc, PortLostError):
        return f"it closed before the first reply ({exc.reason}): is another client using it?"
    if isinstance(exc, TransportError):
        return f"{exc.reason}: check --port"
    return f"{type(exc).__name__}: {exc}"


async def find_arm(port: str, settings: RobotSettings, *, connect_timeout_s: float,
                   reply_timeout_s: float, not_done: str) -> None:
    """Open ``port`` as the driver does, wait for the first valid reply, close it; raises
    :class:`NoArmError` naming the port, ``not_done`` (what did not happen), why, and what to
    check."""
    from armbench.drivers.host.arm import Arm

    arm = Arm.connect(port, settings, reply_timeout_s=reply_timeout_s,
                      connect_timeout_s=connect_timeout_s)
    try:
        await arm.open()
    except (ArmbenchError, OSError, TimeoutError) as exc:
        raise NoArmError(port, f"no arm answers, {not_done}: "
                               f"{_why(exc, connect_timeout_s)}") from exc
    finally:
        await arm.close()


async def probe_arm(plan: BenchPlan) -> None:
    """:func:`find_arm` on the plan's port when its target is an arm already there; nothing of
    the run is made."""
    if not needs_probe(plan.target):
        return
    where = ("no run folder was made" if plan.resume is None
             else f"the run folder {plan.out_dir} is left as it was")
    await find_arm(plan.port, plan.settings, connect_timeout_s=plan.connect_timeout_s,
                   reply_timeout_s=plan.reply_timeout_s,
                   not_done=f"the run did not begin ({where})")


async def probe_arms(plans: Sequence[BenchPlan]) -> None:
    """:func:`probe_arm` for every plan that needs it, at once; the first port (in the plans'
    order) where no arm answers raises."""
    failures = await asyncio.gather(*(probe_arm(plan) for plan in plans),
                                    return_exceptions=True)
    for failure in failures:
        if isinstance(failure, BaseException):
            raise failure


def probe_arms_sync(plans: Sequence[BenchPlan]) -> None:
    """:func:`probe_arms` on a loop of its own (none is made when no plan needs one)."""
    if any(needs_probe(plan.target) for plan in plans):
        asyncio.run(probe_arms(plans))
