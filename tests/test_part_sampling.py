"""A capture part's truth samples and blocks (``drivers/capture/part.py``): the truth taken at
the first reply of each ``period_s`` slot that has one, a missing truth tried again at the next
reply, a block written when full or when its interval has passed. Checked against the rule
written out here reply by reply, on times that fall on, just before and just after the
boundaries, since the writer runs its checks only from a precomputed time on; through the
writer's ``reply`` and through the compiled open block the driver writes to (``reply_sink``)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.drivers.capture.open_block import IN_FLAG, OpenBlock
from armbench.drivers.capture.part import PartWriter, read_part
from armbench.drivers.model.protocol import Reply

REPLY = Reply(1000, 2000, 3000, 4000).encode()


def _expected(t0_s: float, period_s: float, records: int, interval_s: float,
              times: list[float], truths: list[tuple[float, ...] | None],
              ) -> tuple[list[int], list[int]]:
    """The replies whose truth is sampled (indices) and the records of each block, by the rule
    itself."""
    slot, sampled = -1.0, []
    blocks, n, last_flush = [], 0, t0_s
    for i, (t, q) in enumerate(zip(times, truths, strict=True)):
        n += 1
        if (t - t0_s) // period_s != slot and q is not None:
            slot = (t - t0_s) // period_s
            sampled.append(i)
        if n >= records or t - last_flush >= interval_s:
            blocks.append(n)
            n, last_flush = 0, t
    if n:
        blocks.append(n)
    return sampled, blocks


_STEP = st.one_of(st.sampled_from([0.0, 0.0024, 0.1, 0.7]),
                  st.floats(0.0, 0.3, allow_nan=False),
                  st.sampled_from([0.1 - 1e-12, 0.1 + 1e-12, 1e-7]))


@pytest.mark.parametrize("via", ["writer", "sink"])
@settings(max_examples=150, deadline=None)
@given(t0_s=st.sampled_from([0.0, 10.0, 1234.5678]), period_s=st.sampled_from([0.1, 0.05]),
       records=st.integers(1, 9), interval_s=st.sampled_from([0.25, 1.0, 20.0]),
       steps=st.lists(st.tuples(_STEP, st.booleans()), max_size=60))
def test_truth_and_blocks_follow_the_rule(tmp_path_factory: pytest.TempPathFactory, via: str,
                                          t0_s: float, period_s: float, records: int,
                                          interval_s: float,
                                          steps: list[tuple[float, bool]]) -> None:
    path = tmp_path_factory.mktemp("part") / "x.part"
    times: list[float] = []
    truths: list[tuple[float, ...] | None] = []
    t = t0_s
    for dt, has in steps:
        t += dt
        times.append(t)
        truths.append((t, -t) if has else None)
    current: list[tuple[float, ...] | None] = [None]

    writer = PartWriter(path, t0_s, truth=lambda: current[0], period_s=period_s,
                        batch_records=records, batch_interval_s=interval_s)
    reply = writer.reply if via == "writer" else writer.reply_sink().reply
    for t_s, q in zip(times, truths, strict=True):
        current[0] = q
        reply(t_s, REPLY)
    writer.close()

    blocks = list(read_part(path))
    sampled, want_blocks = _expected(t0_s, period_s, records, interval_s, times, truths)
    assert [len(b.t_s) for b in blocks] == want_blocks
    assert [float(x) for b in blocks for x in b.t_s] == [x - t0_s for x in times]
    assert [float(x) for b in blocks for x in b.truth_t_s] == [times[i] - t0_s for i in sampled]
    assert [tuple(float(v) for v in row) for b in blocks for row in b.truth_rad] == [
        truths[i] for i in sampled]


def test_the_open_block_calls_due_from_its_time_or_when_full() -> None:
    due: list[float] = []
    block = OpenBlock(10.0, 3, due.append)
    block.due_s = 10.5
    block.reply(10.25, REPLY)  # before due_s, one record of three: nothing due
    block.add(10.3, 0, b"$out#")
    assert due == []
    block.reply(10.5, REPLY)  # at due_s, and the block full
    block.due_s = 99.0
    block.reply(10.75, REPLY)  # full already: due again
    assert due == [10.5, 10.75]
    assert block.take() == ([0.25, 10.3 - 10.0, 0.5, 0.75], [IN_FLAG, 0, IN_FLAG, IN_FLAG],
                            [REPLY, b"$out#", REPLY, REPLY])
    assert block.take() == ([], [], [])
