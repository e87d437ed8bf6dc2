"""A peer's text echoed shortened (:mod:`armbench.drivers.model.peer_text`): the first characters
and the whole length, never the megabytes (issue 38: a 10 MB joint name was echoed whole into a ROS
2
status, an event and a log line; the same path end to end: ``tests/test_ros2_node.py``)."""

from __future__ import annotations

import pytest

from armbench.drivers.model.peer_text import MAX_ECHO_CHARS, peer_repr, peer_str


def test_short_text_is_echoed_as_it_is() -> None:
    assert peer_str("j1") == "j1"
    assert peer_repr("j1") == "'j1'" and peer_repr(["j1", "j2"]) == "['j1', 'j2']"
    assert peer_repr(()) == "()" and peer_repr([]) == "[]" and peer_repr(3.5) == "3.5"


@pytest.mark.parametrize(("value", "start"), [
    ("x" * 10_000_000, "'xxx"), (["x" * 10_000_000, "j2"], "['xxx"), (["j"] * 1_000_000, "['j', "),
    ([["y" * 5000] * 1000] * 1000, "[['yyy")])
def test_long_text_is_cut_and_its_length_said(value: object, start: str) -> None:
    echo = peer_repr(value)
    assert len(echo) <= 2 * MAX_ECHO_CHARS + 60, len(echo)
    assert echo.startswith(start) and "…(" in echo


def test_the_lengths_said_are_the_peers() -> None:
    assert peer_str("x" * 1000).endswith("…(1000 characters)")
    assert peer_repr(["j"] * 1000).endswith("…(1000 items)]")
    assert "…(10000000 characters)" in peer_repr(["x" * 10_000_000])
