"""Watching a start-up recovery: the motion of each joint at the cut, the replies after power-on
until the arm is back (within tolerance and still) or the time-out, and the rescue of an arm that
did not come back. Time is the running loop's."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Final

from armbench.bench.suites._common import emulator_of, loop_time, rad_list, settled_state
from armbench.bench.suites.base import ReReferencing, SuiteContext
from armbench.bench.suites.recovery_judge import STILL_RAD, RecoveryJudge
from armbench.bench.suites.startup_contract import STARTUP
from armbench.drivers.host.arm import ReplyTimeoutError, WaitTimeoutError

if TYPE_CHECKING:
    from armbench.drivers.host.arm import JointState

__all__ = ["MOTION_WINDOW_S", "await_recovery", "motion_at", "rescue", "stalled_joints"]

#: Motion at the cut is read over this window of replies (s): at duty ≥ 10 a moving joint
#: covers more than ``STILL_RAD`` in it.
MOTION_WINDOW_S: Final = 0.05


def motion_at(recent: Sequence[JointState], last: JointState) -> list[str]:
    """Each joint's motion (``stopped``, ``cw``, ``ccw``) over the last ``MOTION_WINDOW_S`` of
    replies before ``last``."""
    earlier = [s for s in recent if s.t_s <= last.t_s - MOTION_WINDOW_S]
    if not earlier:
        return ["stopped"] * len(last.q_rad)
    ref = earlier[-1]
    out = []
    for a, b in zip(ref.q_rad, last.q_rad, strict=True):
        d = b - a
        out.append("stopped" if abs(d) <= STILL_RAD else "cw" if d > 0 else "ccw")
    return out


def stalled_joints(arm: Any) -> list[int] | None:
    """Joints (1-based) whose start-up recovery is stuck at a hard limit (emulator only)."""
    emu = emulator_of(arm)
    if emu is None:
        return None
    out = []
    for k, board in enumerate(getattr(emu, "boards", ())):
        model = getattr(board, "model", None)
        if model is not None and getattr(model, "homing_failed", False):
            out.append(k + 1)
    return out


async def await_recovery(arm: Any, judge: RecoveryJudge, timeout_s: float,
                         log: Callable[..., Any]) -> RecoveryJudge:
    """Watch the replies after power-on (loop time ``judge.t_on``) until ``judge`` finds the arm
    back or ``timeout_s`` has passed; returns ``judge``, which holds what it saw. Silence is
    expected while a joint 1 recovery runs (the master starts its loop afterwards), so reply
    timeouts are waited through; a lost port raises. Each reply is judged as the driver takes it
    in (a predicate of :meth:`wait_state`), so the watching task wakes once, not once per
    reply."""
    loop = asyncio.get_running_loop()
    deadline = judge.t_on + timeout_s
    while True:
        remaining = deadline - loop.time()
        if remaining <= 0:
            break
        try:
            await arm.wait_state(judge.take, timeout_s=remaining)
        except WaitTimeoutError:
            break
        except ReplyTimeoutError:
            continue
        return judge
    log(event=STARTUP.ev_timeout, after_s=round(loop.time() - judge.t_on, 6))
    return judge


async def rescue(ctx: SuiteContext, log: Callable[..., Any]) -> None:
    """After a failed recovery: re-reference the arm so the campaign can go on. With a power switch
    that can (:class:`~armbench.bench.suites.base.ReReferencing`: the emulator's on ``fake://``,
    the firmware harness's on ``avr://``): power off, re-reference (what an operator re-homing the
    joints and erasing the EEPROMs achieves), power on. With a relay or the operator prompt:
    nothing can be done from here; the next trial errors if the arm is unusable."""
    power = ctx.power
    if power is None or not isinstance(power, ReReferencing):
        log(STARTUP.ev_rescue, done=False, reason="operator must re-reference the arm")
        return
    await power.power_off()
    await power.re_reference()
    await asyncio.sleep(float(ctx.params["off_s"]))
    await power.power_on()
    t = loop_time()
    try:
        await ctx.arm.wait_state(lambda s: s.t_s >= t, timeout_s=5.0)
        await settled_state(ctx.arm, 0.1)
    except (ReplyTimeoutError, WaitTimeoutError) as exc:
        # The failure was measured; the next trial will find the arm unusable and error.
        log(STARTUP.ev_rescue, done=False, reason=f"the arm did not come back: {exc}")
        return
    log(STARTUP.ev_rescue, done=True, q_rad=rad_list(ctx.arm.state.q_rad))
