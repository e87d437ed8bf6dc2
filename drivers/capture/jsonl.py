"""Traffic capture: every frame in and out of the driver as JSON Lines, and replay of a capture.

One record per line::

    {"t_s": 0.0123, "dir": "out", "frame": "$01000,99,...#", "error": null}
    {"t_s": 0.0150, "dir": "in",  "frame": "$01000,00000,00000,00000#", "error": null}
    {"t_s": 0.0170, "dir": "in",  "frame": "$0x000,0", "error": "bytes outside a frame"}

``t_s`` is seconds since the capture started, on the event loop's clock (virtual seconds against
``fake://``); ``dir`` is ``"out"`` (host → arm) or ``"in"`` (arm → host); ``frame`` the frame as
ASCII (non-ASCII bytes of a bad stretch as ``\\xNN``; at most its first 64 bytes); ``error`` the
framer's reason for a stretch that was not a valid frame, else ``null``. Records are buffered and
written in batches (:data:`BATCH_RECORDS` records or :data:`BATCH_INTERVAL_S` seconds, whichever
comes first) so memory stays bounded however long the capture runs.

A capture may be bounded in size (``max_bytes``, ``[bench] capture_max_bytes``): the record that
would cross the bound (less :data:`EVENT_RESERVE_BYTES`) is not written; one event line says the
capture stopped, and nothing more is written (the run itself goes on)::

    {"t_s": 81.25, "event": "capture stopped: the size bound of 1000000 bytes was reached"}

Readers (:func:`read_capture`, the report) skip event lines.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import IO, Any, Final, Literal, NamedTuple, Protocol

from armbench.drivers.model.bounds import Bound, check, check_whole
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.numbers import finite_float
from armbench.drivers.model.protocol import Command
from armbench.drivers.model.settings import SettingsError
from armbench.drivers.model.user_files import FileRefused, open_regular_file

__all__ = [
    "BATCH_INTERVAL_S",
    "BATCH_RECORDS",
    "EVENT_RESERVE_BYTES",
    "CaptureError",
    "CaptureRecord",
    "CaptureWriter",
    "ReplayCommand",
    "ReplySink",
    "capture_end_s",
    "capture_options",
    "capture_stopped",
    "merge_capture",
    "not_a_capture",
    "open_capture_file",
    "read_capture",
    "shift_capture",
    "stop_event",
]

#: Records buffered before a write.
BATCH_RECORDS: Final = 512
#: Loop seconds after which buffered records are written even if the batch is not full.
BATCH_INTERVAL_S: Final = 1.0

Direction = Literal["in", "out"]

#: Bytes a bounded capture keeps free for its stop event (a longer line than any stop event).
EVENT_RESERVE_BYTES: Final = 160
#: Bytes of one capture line at most when reading (a record is a frame of a few dozen bytes, or
#: the bytes of one read the framer dropped): a longer line is not a capture's, and is not loaded.
MAX_LINE_BYTES: Final = 1 << 20


class CaptureError(ArmbenchError, ValueError):
    """A capture file cannot be written or is not a valid capture; names the file and line."""

    def __init__(self, path: str, line: int | None, reason: str) -> None:
        where = f"{path}:{line}" if line is not None else path
        super().__init__(f"{where}: {reason}")
        self.path = path
        self.line = line
        self.reason = reason


#: What a run directory holds beside its capture, and what a user may give instead of it.
_CAPTURE_NAMES: Final = ("capture.mcap", "capture.jsonl")
#: How a run record's ``results.json`` begins (``armbench.record``'s schema, not imported: the
#: record layer is above this one).
_RUN_RECORD_MARK: Final = b'"schema": "armbench-run/'


def open_capture_file(path: str | Path) -> IO[bytes]:
    """The capture file ``path`` opened for reading; a missing file, a directory (a run
    directory: its capture is named), a FIFO or a device is a :class:`CaptureError`, at once
    (a FIFO nobody writes to would block the reader for ever)."""
    try:
        return open_regular_file(path, "a capture")
    except FileRefused as exc:
        p = Path(path)
        inside = [p / name for name in _CAPTURE_NAMES if (p / name).is_file()] if p.is_dir() \
            else []
        hint = f" (give {inside[0]})" if inside else ""
        raise CaptureError(str(path), None, exc.reason + hint) from None


def _head(fh: IO[bytes]) -> bytes:
    """The first 4 KiB of the open file ``fh`` (read again from its start)."""
    fh.seek(0)
    return fh.read(4096)


def not_a_capture(path: Path, head: bytes, first: object = None) -> CaptureError | None:
    """The error for a file that is another of a run's files given as a capture (its
    ``results.json``, or the journal beside it), judged from its first bytes ``head`` and its
    first JSON object ``first``; None when it is not one of them."""
    if _RUN_RECORD_MARK in head:
        what = "a run record (results.json)"
    elif isinstance(first, dict) and {"suite", "trial"} <= first.keys():
        what = "a run record's journal (results.journal.jsonl)"
    else:
        return None
    return CaptureError(str(path), None, f"is {what}, not a capture: give the run's "
                                         f"{' or '.join(_CAPTURE_NAMES)} (beside it)")


class CaptureRecord(NamedTuple):
    """One line of a capture file."""

    t_s: float
    dir: Direction
    frame: str
    error: str | None


#: Record times (s) whose text :func:`_seconds_text` makes (others go through ``json``).
_FAST_T_MIN_S: Final = 1e-3
_FAST_T_MAX_S: Final = 1e5


def _seconds_text(t: float) -> str:
    """``repr(round(t, 9))``, which ``json.dumps`` writes for the rounded time, for
    ``_FAST_T_MIN_S <= t < _FAST_T_MAX_S`` at a third of the cost: ``%.9f`` rounds to the same
    decimal (correctly rounded, 9 places), and a decimal of at most 15 significant digits is the
    shortest one naming its double, i.e. the repr, less the trailing zeros (and no exponent in
    this range)."""
    text = f"{t:.9f}".rstrip("0")
    return text + "0" if text.endswith(".") else text


def _plain(text: str) -> bool:
    """Whether ``text`` goes into JSON unchanged: printable ASCII without '"' and '\\' (every
    valid frame); anything else is written by ``json.dumps``."""
    return text.isascii() and text.isprintable() and '"' not in text and "\\" not in text


#: A line as :meth:`CaptureWriter.frame` writes it (time, direction, a frame that needs no JSON
#: escaping, no error): :func:`read_capture` reads it without ``json``, to the same record.
_FRAME_LINE: Final = re.compile(rb'\{"t_s": (\d{1,5}\.\d{1,9}), "dir": "(in|out)", '
                                rb'"frame": "([ !#-\[\]-~]*)", "error": null\}\n?')


def frame_text(data: bytes) -> str:
    """ASCII text of wire bytes; other bytes as ``\\xNN``."""
    return data.decode("ascii", "backslashreplace")


class ReplySink(Protocol):
    """Where the driver's per-reply path writes each valid reply
    (:meth:`CaptureWriter.reply_sink`)."""

    def reply(self, t_s: float, data: bytes) -> None:
        """One valid reply, the wire bytes of exactly one frame, read at loop time ``t_s``."""


class CaptureWriter:
    """Appends records to a JSON Lines file in batches. Times are given by the caller (loop time)
    and stored relative to ``t0_s``."""

    def __init__(self, path: str | Path, t0_s: float, *, batch_records: int = BATCH_RECORDS,
                 batch_interval_s: float = BATCH_INTERVAL_S, max_bytes: int | None = None) -> None:
        self.path = Path(path)
        self.max_bytes = max_bytes
        """The size bound of the file (bytes, stop event included), None: unbounded."""
        self.stopped = False
        """Whether the bound was reached (the capture stopped)."""
        self._size = 0
        self._last_t_s = t0_s
        self.t0_s = t0_s
        self.batch_records = max(1, batch_records)
        self.batch_interval_s = batch_interval_s
        self.records = 0
        """Records accepted so far."""
        self.batches = 0
        """Batches written so far."""
        self._buf: list[str] = []
        self._last_flush = t0_s
        try:
            self._fh: IO[str] | None = self.path.open("w", encoding="ascii")
        except OSError as exc:
            raise CaptureError(str(self.path), None,
                               f"cannot write: {exc.strerror or exc}") from exc

    @property
    def buffered(self) -> int:
        """Records waiting for the next batch (never more than ``batch_records``)."""
        return len(self._buf)

    def write(self, t_s: float, direction: Direction, frame: str, error: str | None) -> None:
        """Add one record (``t_s`` in loop seconds)."""
        if error is None and _plain(frame):
            self.frame(t_s, direction, frame)
            return
        if self._fh is None:
            return
        self._buf.append(json.dumps({"t_s": round(t_s - self.t0_s, 9), "dir": direction,
                                     "frame": frame, "error": error}))
        self._added(t_s)

    def frame(self, t_s: float, direction: Direction, frame: str) -> None:
        """Add a record without error whose text needs no JSON escaping (a frame the codec
        validated or encoded: digits, commas, '$' and '#'): :meth:`write` without the check."""
        if self._fh is None:
            return
        t = t_s - self.t0_s
        if type(t) is float and _FAST_T_MIN_S <= t < _FAST_T_MAX_S:  # json.dumps's line, cheaper
            self._buf.append(f'{{"t_s": {_seconds_text(t)}, "dir": "{direction}", '
                             f'"frame": "{frame}", "error": null}}')
        else:
            self._buf.append(json.dumps({"t_s": round(t, 9), "dir": direction, "frame": frame,
                                         "error": None}))
        self._added(t_s)

    def reply(self, t_s: float, data: bytes) -> None:
        """Add a reply the codec validated, as the wire bytes of exactly one frame (the
        driver's short path): :meth:`frame` with ``"in"``."""
        self.frame(t_s, "in", data.decode("ascii"))

    def reply_sink(self) -> ReplySink:
        """What the driver hands each valid reply to: this writer (:meth:`reply`), or a faster
        object of a subclass that records the same."""
        return self

    def _added(self, t_s: float) -> None:
        self.records += 1
        self._last_t_s = t_s
        if len(self._buf) >= self.batch_records or t_s - self._last_flush >= self.batch_interval_s:
            self.flush(t_s)

    def flush(self, t_s: float | None = None) -> None:
        """Write the buffered records out now."""
        if self._fh is None or not self._buf:
            return
        text = "\n".join(self._buf) + "\n"
        if (self.max_bytes is not None
                and self._size + len(text) > self.max_bytes - EVENT_RESERVE_BYTES):
            self._stop()
            return
        self._fh.write(text)
        self._fh.flush()
        self._size += len(text)
        self._buf.clear()
        self.batches += 1
        if t_s is not None:
            self._last_flush = t_s

    def _stop(self) -> None:
        """Write the buffered records that fit within the bound, then the stop event; close."""
        assert self._fh is not None and self.max_bytes is not None
        fitting: list[str] = []
        room = self.max_bytes - EVENT_RESERVE_BYTES - self._size
        for line in self._buf:
            if len(line) + 1 > room:
                break
            fitting.append(line + "\n")
            room -= len(line) + 1
        self._buf.clear()
        self._fh.write("".join(fitting) + stop_event(round(self._last_t_s - self.t0_s, 9),
                                                     self.max_bytes))
        self._fh.close()
        self._fh = None
        self.stopped = True

    def close(self) -> None:
        """Flush and close (idempotent)."""
        if self._fh is None:
            return
        try:
            self.flush()
        finally:
            self._fh.close()
            self._fh = None


def shift_capture(src: IO[bytes], dst: IO[bytes], offset_s: float, *, room: int | None = None,
                  max_bytes: int | None = None) -> int:
    """Copy the records of ``src`` to ``dst`` with ``offset_s`` added to each ``t_s``: a capture
    made on another clock (a trial measured in a worker) moved onto the run's. Lines as
    :class:`CaptureWriter` writes them are rewritten as text, as it would have written them;
    others go through ``json``; a line that is not a record is copied unchanged. Returns the
    lines copied, or -1 when ``room`` (bytes) ran out: the line that did not fit was replaced by
    the stop event of the bound ``max_bytes``, and the rest was left out."""
    lines = 0
    out: list[bytes] = []
    t = 0.0
    for line in src:
        if line.startswith(b'{"t_s": '):
            end = line.find(b",", 8)
            try:
                t = float(line[8:end]) + offset_s
            except ValueError:
                t = math.nan
            if _FAST_T_MIN_S <= t < _FAST_T_MAX_S:
                line = b'{"t_s": ' + _seconds_text(t).encode() + line[end:]
            else:
                line = _shifted(line, offset_s)
        elif line.strip():
            line = _shifted(line, offset_s)
        else:
            lines += 1
            continue
        if room is not None:
            room -= len(line)
            if room < 0:
                event_t = round(t, 9) if math.isfinite(t) else 0.0
                out.append(stop_event(event_t, max_bytes or 0).encode())
                dst.write(b"".join(out))
                return -1
        lines += 1
        out.append(line)
        if len(out) >= BATCH_RECORDS:
            dst.write(b"".join(out))
            out.clear()
    dst.write(b"".join(out))
    return lines


def _shifted(line: bytes, offset_s: float) -> bytes:
    try:
        obj = json.loads(line)
        obj["t_s"] = round(float(obj["t_s"]) + offset_s, 9)
    except (ValueError, TypeError, KeyError):
        return line if line.endswith(b"\n") else line + b"\n"
    return json.dumps(obj).encode() + b"\n"


#: The capture's size bound: a byte at least, in bytes (``[bench] capture_max_bytes``) or in
#: megabytes (``--capture-max-mb``).
_CAPTURE_BYTES = Bound(1, math.inf, "bytes", whole=True)
_CAPTURE_MB = Bound(1e-6, math.inf, "MB")


def capture_options(bench: Mapping[str, object], enabled: bool | None = None,
                    max_mb: float | None = None) -> tuple[bool, int | None]:
    """Whether a run captures its traffic and the capture's size bound (bytes, None: unbounded),
    from ``[bench] capture`` (default true) and ``capture_max_bytes`` (default none), overridden
    by ``--no-capture`` (``enabled`` False) and ``--capture-max-mb``. SettingsError names the
    offending value."""
    capture = bench.get("capture", True)
    if not isinstance(capture, bool):
        raise SettingsError("bench.capture", capture, "must be true or false")
    max_bytes = bench.get("capture_max_bytes")
    if max_bytes is not None:
        max_bytes = check_whole("bench.capture_max_bytes", max_bytes, _CAPTURE_BYTES)
    if enabled is not None:
        capture = enabled
    if max_mb is not None:
        max_bytes = int(check("--capture-max-mb", max_mb, _CAPTURE_MB) * 1e6)
    return capture, max_bytes


def stop_event(t_s: float, max_bytes: int) -> str:
    """The event line that ends a capture stopped by its size bound (``t_s`` on its clock)."""
    return json.dumps({"t_s": t_s, "event": f"capture stopped: the size bound of {max_bytes} "
                                            "bytes was reached"}) + "\n"


def _tail_lines(path: Path, size: int = 4096) -> list[bytes]:
    """The complete lines in the last ``size`` bytes of ``path`` (none if it is missing)."""
    try:
        with open_regular_file(path, "a capture") as fh:
            fh.seek(0, 2)
            end = fh.tell()
            fh.seek(max(0, end - size))
            data = fh.read()
    except (OSError, FileRefused):
        return []
    lines = data.split(b"\n")
    return lines[1:-1] if end > size else lines[:-1]


def capture_stopped(path: Path) -> bool:
    """Whether the capture file ``path`` ends with the event of a stop at its size bound."""
    tail = _tail_lines(path)
    return bool(tail) and b'"event": "capture stopped' in tail[-1]


def capture_end_s(path: Path) -> float | None:
    """``t_s`` of the last record of capture ``path`` (None: no file or no readable record):
    where a resumed run's clock continues at the earliest, so the capture never jumps back."""
    for line in reversed(_tail_lines(path)):
        try:
            t = json.loads(line).get("t_s")
        except (ValueError, AttributeError):
            continue
        t_s = finite_float(t)
        if t_s is not None:
            return t_s
    return None


def merge_capture(part: Path, capture: Path, offset_s: float = 0.0,
                  max_bytes: int | None = None) -> bool:
    """Append the capture ``part`` to ``capture`` with ``offset_s`` added to its times
    (:func:`shift_capture`), within the size bound ``max_bytes`` of ``capture``: the line that
    would cross it is replaced by the stop event, and nothing is appended to a capture that
    stopped. Returns whether ``capture`` is stopped now."""
    if max_bytes is not None and capture_stopped(capture):
        return True
    with part.open("rb") as src, capture.open("ab") as dst:
        room = None if max_bytes is None else max_bytes - EVENT_RESERVE_BYTES - dst.tell()
        return shift_capture(src, dst, offset_s, room=room, max_bytes=max_bytes) < 0


def _record(obj: Any, path: str, line: int) -> CaptureRecord | None:
    if not isinstance(obj, dict):
        raise CaptureError(path, line, "is not a JSON object")
    if "event" in obj and "dir" not in obj:
        return None
    t, d, f, e = obj.get("t_s"), obj.get("dir"), obj.get("frame"), obj.get("error")
    t_s = finite_float(t)
    if t_s is None:
        raise CaptureError(path, line, f"t_s {t!r} is not a finite number")
    if d not in ("in", "out"):
        raise CaptureError(path, line, f"dir {d!r} is not 'in' or 'out'")
    if not isinstance(f, str):
        raise CaptureError(path, line, f"frame {f!r} is not a string")
    if e is not None and not isinstance(e, str):
        raise CaptureError(path, line, f"error {e!r} is not a string or null")
    return CaptureRecord(t_s, d, f, e)


def _json_record(raw: bytes, path: str, n: int, fh: IO[bytes]) -> CaptureRecord | None:
    """The record line ``n`` of ``path`` holds, read with ``json`` (None for an event line);
    :class:`CaptureError` if it is not one."""
    try:
        obj = json.loads(raw.decode("ascii"))
    except UnicodeDecodeError as exc:
        raise CaptureError(path, n, f"is not text: byte 0x{raw[exc.start]:02x} at column "
                                    f"{exc.start + 1}") from None
    except ValueError as exc:
        raise not_a_capture(Path(path), _head(fh)) or CaptureError(
            path, n, f"is not JSON: {exc}") from None
    except RecursionError:
        raise CaptureError(path, n, "is not a capture record: JSON nested too deeply") from None
    try:
        return _record(obj, path, n)
    except CaptureError as exc:
        raise not_a_capture(Path(path), _head(fh), obj) or exc from None


def read_capture(path: str | Path) -> Iterator[CaptureRecord]:
    """Every record of a JSON Lines capture file, in order (streamed: the file is not loaded
    whole); event lines (a stop at the size bound) are skipped. Either format:
    :func:`armbench.drivers.capture.read.open_capture`.

    A line that is not a record (not text, not JSON, nested beyond the parser's depth, longer than
    :data:`MAX_LINE_BYTES`) and a record whose time is before the previous one's are a
    :class:`CaptureError` naming the line."""
    p = str(path)
    last: tuple[float, int] | None = None  # the previous record's time and line
    with open_capture_file(path) as fh:
        for n, raw in enumerate(iter(lambda: fh.readline(MAX_LINE_BYTES + 1), b""), 1):
            if len(raw) > MAX_LINE_BYTES:
                raise CaptureError(p, n, f"is longer than {MAX_LINE_BYTES} bytes: not a "
                                         "capture record")
            written = _FRAME_LINE.fullmatch(raw)
            if written is not None:
                record: CaptureRecord | None = CaptureRecord(
                    float(written[1]), "in" if written[2] == b"in" else "out",
                    written[3].decode("ascii"), None)
            elif not raw.strip():
                continue
            else:
                record = _json_record(raw, p, n, fh)
            if record is None:
                continue
            if last is not None and record.t_s < last[0]:
                raise CaptureError(p, n, f"time {record.t_s:.9g} s before the previous "
                                         f"{last[0]:.9g} s (line {last[1]})")
            last = (record.t_s, n)
            yield record


class ReplayCommand(NamedTuple):
    """A host → arm command of a capture: seconds after the first command, the command, and
    seconds after the capture started."""

    t_s: float
    command: Command
    capture_t_s: float
