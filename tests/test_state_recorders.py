"""The driver's state recorders (``Arm.record_states``, the one of a streamed path): each is its
own buffer, taken out of the link by identity when its block ends.

Two empty buffers are equal lists, so taking one out by value (``list.remove``) took out the
first equal one: another recorder. Its owner then got no state again, and the ended one grew
for as long as the link lived (issue 38: a ROS 2 trajectory to where the arm already was froze
``/joint_states`` and grew the node by ~28 MB/s). On ``fake://``, virtual time, no mocks.
"""

from __future__ import annotations

import numpy as np

from armbench.drivers.host.arm import Arm
from armbench.drivers.host.move_targets import wire_command
from armbench.drivers.host.paths import LOOKAHEAD_S, stream_path
from armbench.fakes.clock.vclock import run_virtual


def test_an_ended_recorder_takes_out_itself_not_an_equal_one() -> None:
    async def main() -> tuple[list[int], int, int]:
        async with Arm.connect("fake://") as arm:
            with arm.record_states() as outer:
                with arm.record_states() as inner:
                    pass  # both empty (equal) when the inner one ends
                seq = arm.state.seq
                await arm.wait_state(lambda s: s.seq > seq + 100)
                return [s.seq for s in outer], len(inner), arm.state.seq

    outer, inner_n, last = run_virtual(main())
    assert len(outer) > 100 and inner_n == 0, (len(outer), inner_n)
    # every reply once, in order, up to the newest (fake:// hands them over one per chunk)
    assert outer == list(range(outer[0], last + 1))


def test_a_path_that_ends_at_once_leaves_the_other_recorders_fed() -> None:
    """A path to where the arm is arrives on the state it has: the path's buffer is still empty
    when it ends, as is a recorder that was just drained (the ROS 2 node's)."""

    async def main() -> tuple[int, int]:
        async with Arm.connect("fake://") as arm:
            q = arm.state.q_rad
            here = wire_command(q, (50,) * 4, arm.settings)
            pts = np.array([arm.state.tcp_m(arm.settings)] * 2)
            with arm.record_states() as mine:
                del mine[:]  # drained, as the node drains its buffer each reply
                run = await stream_path(arm, pts, [here, here], 0.0,
                                        arm.default_tolerance_rad(), LOOKAHEAD_S, None)
                assert run.duration_s <= 0.0 and not run.states  # arrived on the state it had
                seq = arm.state.seq
                await arm.wait_state(lambda s: s.seq > seq + 100)
                return len(mine), len(run.states)

    mine_n, path_n = run_virtual(main())
    assert mine_n > 100, mine_n  # before: 0, the node's /joint_states frozen
    assert path_n == 0, path_n  # before: the ended path's buffer grew with every reply
