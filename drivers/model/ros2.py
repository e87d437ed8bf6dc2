"""ROS 2 messages of the arm's traffic: schemas (``ros2msg``) and CDR encoders, no ROS install.

What a ROS user looks at: ``sensor_msgs/msg/JointState`` (joint names ``j1``..``j4``, radians in
the protocol convention, the URDF's joint positions), ``tf2_msgs/msg/TFMessage`` (the link frames
of :mod:`armbench.drivers.model.urdf`, from the DH table of
:mod:`armbench.drivers.model.kinematics`),
``std_msgs/msg/String``, and two messages of armbench's own: ``armbench_msgs/msg/UartFrames``
(consecutive raw frames of one direction, each with its time) and ``armbench_msgs/msg/BenchEvent``.

The hot messages have a fixed layout (fixed names and frame ids), so each is one precompiled
``struct`` format: a JointState costs one ``pack`` call. Encodings are little-endian CDR
(encapsulation ``00 01 00 00``), checked against an independent decoder (``rosbags``) in the tests.
"""

from __future__ import annotations

import functools
import json
import math
import struct
from collections.abc import Callable, Sequence
from typing import Any, Final

import numpy as np
import numpy.typing as npt
from mcap_ros2._dynamic import serialize_dynamic

from armbench.drivers.model.kinematics import dh_parameters
from armbench.drivers.model.settings import RobotSettings

__all__ = [
    "BENCH_EVENT",
    "JOINT_NAMES",
    "JOINT_STATE",
    "SCHEMAS",
    "STRING",
    "TF_MESSAGE",
    "UART_FRAMES",
    "JointStateEncoder",
    "TfEncoder",
    "dynamic_encoder",
    "encode_event",
    "encode_string",
    "encode_uart_frames",
    "encode_uart_frames_bytes",
    "link_transforms",
    "link_transforms_many",
    "static_transforms",
]

JOINT_NAMES: Final = ("j1", "j2", "j3", "j4")
JOINT_STATE: Final = "sensor_msgs/msg/JointState"
TF_MESSAGE: Final = "tf2_msgs/msg/TFMessage"
STRING: Final = "std_msgs/msg/String"
UART_FRAMES: Final = "armbench_msgs/msg/UartFrames"
BENCH_EVENT: Final = "armbench_msgs/msg/BenchEvent"

_SEP = "=" * 80 + "\n"
_TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
_HEADER = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"

#: ``ros2msg`` schema text of each message type (dependencies appended as ``ros2 bag`` does).
SCHEMAS: Final[dict[str, str]] = {
    JOINT_STATE: ("std_msgs/Header header\nstring[] name\nfloat64[] position\n"
                  "float64[] velocity\nfloat64[] effort\n" + _SEP + _HEADER + _SEP + _TIME),
    TF_MESSAGE: ("geometry_msgs/TransformStamped[] transforms\n" + _SEP
                 + "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\n"
                   "string child_frame_id\ngeometry_msgs/Transform transform\n" + _SEP + _HEADER
                 + _SEP + _TIME + _SEP
                 + "MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\n"
                   "geometry_msgs/Quaternion rotation\n" + _SEP
                 + "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n" + _SEP
                 + "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\n"
                   "float64 w 1\n"),
    STRING: "string data\n",
    UART_FRAMES: ("# Consecutive frames of one direction of the UART link, as the driver framed "
                  "them.\n"
                  "builtin_interfaces/Time stamp  # time of the first frame\n"
                  "int64[] offset_ns  # each frame's time after stamp\n"
                  "string[] frame  # each frame as ASCII, other bytes as \\xNN\n"
                  "string[] error  # the framer's reason for a stretch that was no frame, "
                  "else empty\n" + _SEP + _TIME),
    BENCH_EVENT: ("# Something the bench did or saw: trial_start, trial_end, fault, power_off, "
                  "power_on.\n"
                  "builtin_interfaces/Time stamp\nstring kind\nstring suite\nint32 trial\n"
                  "string detail  # JSON object\n" + _SEP + _TIME),
}

_CDR_HEADER = b"\x00\x01\x00\x00"


class _Layout:
    """Builds a little-endian ``struct`` format for a CDR body with alignment from its start
    (right after the 4-byte encapsulation header); fixed strings are written as bytes."""

    def __init__(self) -> None:
        self.fmt = ["<4s"]
        self.pos = 0
        self.consts: list[Any] = []
        self.slots: list[int] = []  # index into consts of each variable field, in order
        self.offsets: list[int] = []  # byte offset of each variable field in the message

    def _align(self, n: int) -> None:
        pad = -self.pos % n
        if pad:
            self.fmt.append(f"{pad}x")
            self.pos += pad

    def const_u32(self, value: int) -> None:
        self._align(4)
        self.fmt.append("I")
        self.consts.append(value)
        self.pos += 4

    def const_string(self, text: str) -> None:
        data = text.encode() + b"\x00"
        self.const_u32(len(data))
        self.fmt.append(f"{len(data)}s")
        self.consts.append(data)
        self.pos += len(data)

    def var(self, code: str, size: int) -> None:
        self._align(size)
        self.fmt.append(code)
        self.offsets.append(4 + self.pos)
        self.slots.append(len(self.consts))
        self.consts.append(None)
        self.pos += size

    def compile(self) -> tuple[struct.Struct, list[Any]]:
        return struct.Struct("".join(self.fmt)), [_CDR_HEADER, *self.consts]


def _stamp_layout(lay: _Layout, frame_id: str) -> None:
    lay.var("i", 4)
    lay.var("I", 4)
    lay.const_string(frame_id)


def _split_ns(t_ns: int) -> tuple[int, int]:
    sec, nsec = divmod(t_ns, 1_000_000_000)
    return sec, nsec


class _Rows:
    """Many messages of one fixed layout at once: rows of a template, variable fields written
    by column with numpy (the stamps, the float64 values)."""

    def __init__(self, template: bytes, count: int) -> None:
        self.rows = np.tile(np.frombuffer(template, dtype=np.uint8), (count, 1))

    def put(self, offset: int, values: npt.ArrayLike, dtype: str) -> None:
        """Write ``values`` (one row of fields per message) at ``offset`` of each message."""
        data = np.ascontiguousarray(values, dtype=dtype)
        data = data.reshape(len(self.rows), -1)
        width = data.shape[1] * data.dtype.itemsize
        self.rows[:, offset:offset + width] = data.view(np.uint8).reshape(len(self.rows), width)

    def stamp(self, offset: int, t_ns: npt.NDArray[np.int64]) -> None:
        """A ``builtin_interfaces/Time`` (sec, nanosec) at ``offset``."""
        sec, nsec = np.divmod(t_ns, 1_000_000_000)
        self.put(offset, sec, "<i4")
        self.put(offset + 4, nsec, "<u4")

    def messages(self) -> list[bytes]:
        return [row.tobytes() for row in self.rows]


class JointStateEncoder:
    """``sensor_msgs/msg/JointState`` with the names ``j1``..``j4``, positions (rad) and, when
    ``with_effort``, four efforts (the command's PWM duty in percent); velocity empty."""

    def __init__(self, *, with_effort: bool = False, frame_id: str = "") -> None:
        lay = _Layout()
        _stamp_layout(lay, frame_id)
        lay.const_u32(len(JOINT_NAMES))
        for name in JOINT_NAMES:
            lay.const_string(name)
        lay.const_u32(4)
        for _ in range(4):
            lay.var("d", 8)
        lay.const_u32(0)  # velocity
        lay.const_u32(4 if with_effort else 0)
        if with_effort:
            for _ in range(4):
                lay.var("d", 8)
        self._struct, consts = lay.compile()
        self._mid = tuple(consts[3:consts.index(None, 3)])  # frame id .. position count
        self._velocity = (0, 4) if with_effort else (0, 0)
        self._offsets = lay.offsets
        self.with_effort = with_effort

    def encode(self, t_ns: int, q_rad: Sequence[float],
               effort: Sequence[float] | None = None) -> bytes:
        """One message stamped ``t_ns`` (ns of the capture's clock)."""
        sec, nsec = _split_ns(t_ns)
        if self.with_effort:
            assert effort is not None
            return self._struct.pack(_CDR_HEADER, sec, nsec, *self._mid, *q_rad, *self._velocity,
                                     *effort)
        return self._struct.pack(_CDR_HEADER, sec, nsec, *self._mid, *q_rad, *self._velocity)

    def encode_many(self, t_ns: npt.NDArray[np.int64],
                    q_rad: npt.NDArray[np.float64]) -> list[bytes]:
        """Messages without effort stamped ``t_ns[i]`` with positions ``q_rad[i]``: what
        :meth:`encode` gives for each, built with numpy."""
        assert not self.with_effort
        rows = _Rows(self.encode(0, (0.0,) * len(JOINT_NAMES)), len(t_ns))
        rows.stamp(self._offsets[0], t_ns)
        rows.put(self._offsets[2], q_rad, "<f8")  # the positions follow each other
        return rows.messages()


class TfEncoder:
    """``tf2_msgs/msg/TFMessage`` of a fixed list of (parent, child) frames; each transform's
    translation (m) and rotation quaternion (x, y, z, w) vary."""

    def __init__(self, pairs: Sequence[tuple[str, str]]) -> None:
        lay = _Layout()
        lay.const_u32(len(pairs))
        self._n = len(pairs)
        for parent, child in pairs:
            _stamp_layout(lay, parent)
            lay.const_string(child)
            for _ in range(7):
                lay.var("d", 8)
        self._struct, self._consts = lay.compile()
        self._slots = [i + 1 for i in lay.slots]  # +1: the header in front
        self._offsets = lay.offsets

    def encode(self, t_ns: int, poses: Sequence[Sequence[float]]) -> bytes:
        """One message stamped ``t_ns``; ``poses`` holds (tx, ty, tz, qx, qy, qz, qw) per pair."""
        sec, nsec = _split_ns(t_ns)
        values = self._consts.copy()
        slots = self._slots
        k = 0
        for pose in poses:
            values[slots[k]] = sec
            values[slots[k + 1]] = nsec
            for j in range(7):
                values[slots[k + 2 + j]] = pose[j]
            k += 9
        return self._struct.pack(*values)

    def encode_many(self, t_ns: npt.NDArray[np.int64],
                    poses: npt.NDArray[np.float64]) -> list[bytes]:
        """Messages stamped ``t_ns[i]`` with ``poses[i]`` (pairs × 7): what :meth:`encode`
        gives for each, built with numpy."""
        rows = _Rows(self.encode(0, [(0.0,) * 7] * self._n), len(t_ns))
        for k in range(self._n):
            rows.stamp(self._offsets[9 * k], t_ns)
            rows.put(self._offsets[9 * k + 2], poses[:, k, :], "<f8")
        return rows.messages()


@functools.cache
def dynamic_encoder(name: str) -> Callable[[Any], bytes]:
    """``mcap-ros2-support``'s serializer of message type ``name`` (built from its schema text):
    for the rare messages; the hot ones have the fixed-layout encoders above, byte for byte the
    same (checked in the tests) at a twentieth of the cost."""
    encoder: Callable[[Any], bytes] = serialize_dynamic(name, SCHEMAS[name])[name]
    return encoder


def encode_string(text: str) -> bytes:
    """``std_msgs/msg/String``."""
    return dynamic_encoder(STRING)({"data": text})


def _string_seq(texts: Sequence[str]) -> bytes:
    """The elements of a CDR ``string[]`` (its count excluded), starting 4-aligned: each is
    its length, its bytes, a NUL and padding to 4, so one piece per distinct length."""
    if not any(texts):
        return b"\x01\x00\x00\x00\x00\x00\x00\x00" * len(texts)
    pieces = []
    for text in texts:
        data = text.encode("utf-8", "backslashreplace")
        n = len(data) + 1
        pieces.append(struct.pack("<I", n) + data + b"\x00" * (1 + -n % 4))
    return b"".join(pieces)


def _string_seq_rows(rows: npt.NDArray[np.uint8]) -> bytes:
    """:func:`_string_seq` of ASCII texts of one length, one per row of ``rows``: with numpy."""
    n, size = rows.shape
    width = 4 + size + 1 + (-(size + 1) % 4)
    out = np.zeros((n, width), dtype=np.uint8)
    out[:, :4] = np.frombuffer(struct.pack("<I", size + 1), dtype=np.uint8)
    out[:, 4:4 + size] = rows
    return out.tobytes()


def encode_uart_frames_bytes(t0_ns: int, offsets_ns: npt.NDArray[np.int64],
                             frames: Sequence[bytes] | npt.NDArray[np.uint8]) -> bytes:
    """:func:`encode_uart_frames` of valid frames (no errors) given as ASCII bytes, or as the
    rows of a 2-D array when all have one length."""
    n = len(frames)
    if isinstance(frames, np.ndarray):
        seq = _string_seq_rows(frames) if n and frames.shape[1] else _string_seq([""] * n)
    elif n and len(set(map(len, frames))) == 1:
        seq = _string_seq_rows(np.frombuffer(b"".join(frames), dtype=np.uint8).reshape(n, -1))
    else:
        seq = _string_seq([t.decode("ascii", "backslashreplace") for t in frames])
    sec, nsec = _split_ns(t0_ns)
    pad = b"\x00\x00\x00\x00" if n else b""
    return b"".join((_CDR_HEADER, struct.pack("<iII", sec, nsec, n), pad,
                     np.asarray(offsets_ns, dtype="<i8").tobytes(),
                     struct.pack("<I", n), seq,
                     struct.pack("<I", n), _string_seq([""] * n)))[:-3 if n else None]


def encode_uart_frames(t0_ns: int, offsets_ns: Sequence[int] | npt.NDArray[np.int64],
                       frames: Sequence[str], errors: Sequence[str]) -> bytes:
    """``armbench_msgs/msg/UartFrames``: frames at ``t0_ns + offsets_ns[i]``."""
    n = len(frames)
    sec, nsec = _split_ns(t0_ns)
    pad = b"\x00\x00\x00\x00" if n else b""  # int64 elements start 8-aligned
    out = b"".join((_CDR_HEADER, struct.pack("<iII", sec, nsec, n), pad,
                     np.asarray(offsets_ns, dtype="<i8").tobytes(),
                     struct.pack("<I", n), _string_seq(frames),
                     struct.pack("<I", len(errors)), _string_seq(errors)))
    # no padding after the last element: the message ends there
    last = len(errors[-1].encode("utf-8", "backslashreplace")) + 1 if errors else 0
    return out[:len(out) - (-last % 4)]


def encode_event(t_ns: int, kind: str, suite: str = "", trial: int = -1,
                 detail: dict[str, Any] | None = None) -> bytes:
    """``armbench_msgs/msg/BenchEvent``."""
    sec, nsec = _split_ns(t_ns)
    return dynamic_encoder(BENCH_EVENT)({
        "stamp": {"sec": sec, "nanosec": nsec}, "kind": kind, "suite": suite, "trial": trial,
        "detail": json.dumps(detail or {}, sort_keys=True)})


# -- link frames ------------------------------------------------------------------------------

def _quat_z(angle_rad: float) -> tuple[float, float, float, float]:
    half = 0.5 * angle_rad
    return 0.0, 0.0, math.sin(half), math.cos(half)


def _quat_x(angle_rad: float) -> tuple[float, float, float, float]:
    half = 0.5 * angle_rad
    return math.sin(half), 0.0, 0.0, math.cos(half)


def link_names(i: int) -> tuple[str, str, str]:
    """(parent, turned frame, link frame) of joint ``i`` (1..4): joint ``i`` turns
    ``link{i}_root`` about its z axis relative to its parent; ``link{i}`` (DH frame ``i``) is
    fixed to it."""
    parent = "base_link" if i == 1 else f"link{i - 1}"
    return parent, f"link{i}_root", f"link{i}"


#: (parent, child) of the transforms on ``/tf`` (the joints) and ``/tf_static`` (the links).
MOVING_PAIRS: Final = tuple((link_names(i)[0], link_names(i)[1]) for i in range(1, 5))
STATIC_PAIRS: Final = tuple((link_names(i)[1], link_names(i)[2]) for i in range(1, 5))


def link_transforms(q_rad: Sequence[float], settings: RobotSettings) -> list[tuple[float, ...]]:
    """The moving transforms of ``/tf`` for protocol angles ``q_rad``: joint ``i`` is the
    rotation by its DH angle ``θ_i = sign·q_i + offset_i`` about z (no translation)."""
    out: list[tuple[float, ...]] = []
    for q, joint in zip(q_rad, settings.joints, strict=True):
        out.append((0.0, 0.0, 0.0, *_quat_z(joint.to_dh(q))))
    return out


def link_transforms_many(q_rad: npt.NDArray[np.float64],
                         settings: RobotSettings) -> npt.NDArray[np.float64]:
    """:func:`link_transforms` of many rows of angles at once: shape (rows, joints, 7)."""
    sign = np.array([j.sign for j in settings.joints], dtype=np.float64)
    offset = np.array([j.offset_rad for j in settings.joints], dtype=np.float64)
    half = 0.5 * (sign * q_rad + offset)
    out = np.zeros((*q_rad.shape, 7), dtype=np.float64)
    out[..., 5] = np.sin(half)
    out[..., 6] = np.cos(half)
    return out


def static_transforms(settings: RobotSettings) -> list[tuple[float, ...]]:
    """The fixed transforms of ``/tf_static``: DH frame ``i`` in ``link{i}_root`` is
    ``Tz(d_i)·Tx(a_i)·Rx(α_i)`` (Table 1,
    :func:`armbench.drivers.model.kinematics.dh_parameters`)."""
    table: npt.NDArray[np.float64] = dh_parameters(settings.geometry)
    return [(float(a), 0.0, float(d), *_quat_x(float(alpha))) for a, alpha, d in table]
