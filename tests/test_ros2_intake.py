"""The node's intake of trajectories (:mod:`armbench.frontends.ros2_node.intake`): every trajectory
it hears of gets exactly one final status, and every status says whose it is.

No ROS needed: the intake takes a message's fields and rclpy's ``MessageInfo`` as plain values, so
the messages here are ``SimpleNamespace`` objects with the fields of a ``JointTrajectory`` and the
infos dicts as rclpy gives them (the same path with real rclpy and Fast DDS:
``tests/test_ros2_flood.py``).
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from armbench.frontends.ros2_node.intake import MAX_POINTS, Intake, Source, Tag, source_of

NAMES = ["j1", "j2", "j3", "j4"]
GID = bytes(range(16))


def _msg(stamp: tuple[int, int] = (0, 0), points: int = 1) -> Any:
    point = SimpleNamespace(positions=[0.0] * 4, time_from_start=SimpleNamespace(sec=1, nanosec=0))
    return SimpleNamespace(joint_names=NAMES, points=[point] * points,
                           header=SimpleNamespace(stamp=SimpleNamespace(sec=stamp[0],
                                                                        nanosec=stamp[1])))


def _info(seq: int, gid: bytes = GID) -> dict[str, Any]:
    return {"publication_sequence_number": seq,
            "publisher_gid": {"implementation_identifier": "rmw_fastrtps_cpp", "data": gid}}


class _Statuses:
    """What the intake publishes, and how often it woke the loop."""

    def __init__(self) -> None:
        self.sent: list[tuple[Tag, str, dict[str, Any]]] = []
        self.wakes = 0

    def answer(self, tag: Tag, state: str, **fields: Any) -> None:
        self.sent.append((tag, state, fields))

    def wake(self) -> None:
        self.wakes += 1


def test_one_replaced_before_the_loop_took_it_is_preempted_with_its_own_tag() -> None:
    out = _Statuses()
    intake = Intake(out.answer, out.wake)
    intake.receive(_msg((7, 1)), _info(1))
    intake.receive(_msg((0, 0)), _info(2))  # before the loop took the first
    (tag, state, fields), = out.sent
    assert state == "preempted" and tag == Tag(1, (7, 1), Source(GID.hex(), 1))
    assert fields["reason"] == "replaced by trajectory 2 before it started"
    taken = intake.take()
    assert taken is not None and taken.tag == Tag(2, (0, 0), Source(GID.hex(), 2))
    assert intake.take() is None and out.wakes == 2


def test_a_gap_in_a_publishers_sequence_is_answered_once_for_the_whole_gap() -> None:
    out = _Statuses()
    intake = Intake(out.answer, out.wake)
    other = bytes(16)
    for seq, gid in ((1, GID), (1, other), (5, GID), (2, other)):
        intake.receive(_msg(), _info(seq, gid))
        intake.take()
    (tag, state, fields), = out.sent  # the other publisher lost nothing
    assert state == "rejected" and tag == Tag(None, None, Source(GID.hex(), 2, 4))
    assert tag.source is not None and tag.source.as_json() == {"gid": GID.hex(), "seq": 2,
                                                               "seq_last": 4}
    assert "3 trajectories of this publisher (sequence numbers 2..4)" in fields["reason"]


def test_after_close_the_waiting_one_is_handed_back_and_later_ones_aborted() -> None:
    out = _Statuses()
    intake = Intake(out.answer, out.wake)
    intake.receive(_msg(), _info(1))
    waiting = intake.close()
    assert waiting is not None and waiting.tag.id == 1 and out.sent == []
    intake.receive(_msg(), _info(2))
    (tag, state, fields), = out.sent
    assert (tag.id, state, fields) == (2, "aborted", {"reason": "shutdown"})
    assert intake.take() is None


def test_too_many_points_are_not_copied() -> None:
    out = _Statuses()
    intake = Intake(out.answer, out.wake)
    intake.receive(_msg(points=MAX_POINTS + 1), None)
    taken = intake.take()
    assert taken is not None and taken.too_many == MAX_POINTS + 1 and taken.positions == []
    assert taken.tag == Tag(1, (0, 0), None)  # no MessageInfo: no source


def test_a_sequence_number_the_middleware_does_not_support_is_no_source() -> None:
    assert source_of(_info(2**64 - 1)) is None  # rmw's "unsupported"
    assert source_of({"publication_sequence_number": None, "publisher_gid": None}) is None
    assert source_of(_info(3)) == Source(GID.hex(), 3)
