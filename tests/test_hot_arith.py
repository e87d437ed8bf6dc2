"""The emulator loop's hand-compiled arithmetic is the builtin it replaces, value for value."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st

from armbench.drivers.model.protocol import encode_reply
from armbench.fakes.firmware.boards import round_even


@given(st.floats(allow_nan=False, allow_infinity=False)
       | st.integers(-10**9, 10**9).map(lambda k: k / 2)       # ties, both parities
       | st.integers(0, 10**12).map(lambda k: k * 1e-9 * 1e9))  # loop times in ns
def test_round_even_is_round(x: float) -> None:
    assert round_even(x) == round(x)
    assert type(round_even(x)) is int


def test_round_even_refuses_what_round_refuses() -> None:
    for bad, error in ((math.inf, OverflowError), (-math.inf, OverflowError),
                       (math.nan, ValueError)):
        for f in (round, round_even):
            try:
                f(bad)
            except error:
                continue
            raise AssertionError(f"{f.__name__}({bad}) did not raise {error.__name__}")


ticks = st.integers(0, 62_832)


@given(ticks, ticks, ticks, ticks)
def test_encode_reply_is_the_format(j1: int, j2: int, j3: int, j4: int) -> None:
    assert encode_reply(j1, j2, j3, j4) == b"$%05d,%05d,%05d,%05d#" % (j1, j2, j3, j4)


@given(st.integers(-10**6, 10**6), ticks, ticks, st.integers(-10**6, 10**6))
def test_encode_reply_outside_the_table_is_still_the_format(j1: int, j2: int, j3: int,
                                                            j4: int) -> None:
    assert encode_reply(j1, j2, j3, j4) == b"$%05d,%05d,%05d,%05d#" % (j1, j2, j3, j4)
