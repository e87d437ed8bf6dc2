"""The record's journal and the samples kept on disk.

A run's ``results.json`` is rewritten only at checkpoints (a suite begins or ends, the baseline is
set); a trial that ends in between is appended, fsynced, as one line of
``results.journal.jsonl`` beside it (``{"suite": name, "trial": {...}}``), so the cost of keeping
a trial is that trial's size, however many came before. :func:`load_record
<armbench.record.load_record>` replays the journal over ``results.json``, so a record read
after a crash holds every finished trial. A trial's samples, the bulk of a record, are not kept in
memory: :class:`StoredSamples` reads them back from the journal line or the ``results.json`` part
that holds them when they are used.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, TypedDict, overload

from armbench.drivers.model.user_files import FileRefused, open_regular_file
from armbench.record.fields import RecordError
from armbench.record.files import fsync_directory

__all__ = ["JournalEntry", "StoredSamples", "append_line", "journal_path", "read_journal"]


class JournalEntry(TypedDict):
    """One line of the journal: a finished trial (the JSON object of ``Trial.to_json``) of a
    suite."""

    suite: str
    trial: dict[str, Any]


def journal_path(results: Path) -> Path:
    """The journal beside the record file ``results`` (``results.json`` →
    ``results.journal.jsonl``)."""
    return results.with_name(f"{results.stem}.journal.jsonl")


def append_line(path: Path, line: str) -> tuple[int, int]:
    """Append ``line`` (one JSON line, newline included) to the journal ``path`` and fsync it;
    returns its byte offset and length. The directory is fsynced when the file is new."""
    data = line.encode("utf-8")
    new = not path.exists()
    try:
        with path.open("ab") as fh:
            offset = fh.tell()
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as exc:
        raise RecordError(str(path), f"could not be written: {exc.strerror or exc}") from exc
    if new:
        fsync_directory(path.parent)
    return offset, len(data)


def read_journal(path: Path) -> Iterator[tuple[int, JournalEntry]]:
    """The entries of journal ``path`` with their line numbers (nothing if there is none). A last
    line without its newline is a write a crash cut short and is skipped; any other line that is
    not an entry raises a RecordError naming the line."""
    try:  # a FIFO or a device there is refused, not waited on
        fh = open_regular_file(path, "a journal")
    except FileRefused as exc:
        if not os.path.lexists(path):
            return
        raise RecordError(str(path), exc.reason) from None
    with fh:
        for number, raw in enumerate(fh, start=1):
            if not raw.endswith(b"\n"):
                return
            try:
                entry = json.loads(raw)
            except (UnicodeDecodeError, json.JSONDecodeError) as exc:
                raise RecordError(f"{path}:{number}", f"is not valid JSON: {exc}") from None
            if (not isinstance(entry, dict) or not isinstance(entry.get("suite"), str)
                    or not isinstance(entry.get("trial"), dict)):
                raise RecordError(f"{path}:{number}", "is not a journal entry "
                                                      '({"suite": ..., "trial": {...}})')
            yield number, JournalEntry(suite=entry["suite"], trial=entry["trial"])


#: The samples read last, by the StoredSamples that read them: iterating or indexing one trial's
#: samples reads its file once; memory holds one trial's samples at most.
_last_read: tuple[StoredSamples, list[Mapping[str, Any]]] | None = None


class StoredSamples(Sequence[Mapping[str, Any]]):
    """A trial's ``size`` samples as they are on disk: the JSON object of the trial at ``offset``
    (bytes, ``length`` long) in ``path``, a ``results.json`` or, when ``entry``, a journal line
    holding it. Reads the file when used; compares equal to the same samples in a list. The
    writer moves it (:meth:`move`) when it rewrites the file, so a trial's samples stay readable
    for as long as the trial is kept."""

    __slots__ = ("entry", "length", "offset", "path", "size")

    def __init__(self, path: Path, offset: int, length: int, size: int, *, entry: bool) -> None:
        self.path = path
        self.offset = offset
        self.length = length
        self.size = size
        self.entry = entry

    def move(self, path: Path, offset: int, length: int, *, entry: bool) -> None:
        """The same samples, now at ``offset`` in ``path``."""
        self.path, self.offset, self.length, self.entry = path, offset, length, entry

    def _load(self) -> list[Mapping[str, Any]]:
        global _last_read
        if _last_read is not None and _last_read[0] is self:
            return _last_read[1]
        try:
            with self.path.open("rb") as fh:
                fh.seek(self.offset)
                data = json.loads(fh.read(self.length))
        except (OSError, ValueError) as exc:
            raise RecordError(str(self.path), f"the samples at byte {self.offset} cannot be read "
                                              f"back: {exc}") from None
        trial = data["trial"] if self.entry else data
        samples: list[Mapping[str, Any]] = trial["samples"]
        if len(samples) != self.size:
            raise RecordError(str(self.path), f"the samples at byte {self.offset} are not the "
                                              f"{self.size} that were written")
        _last_read = (self, samples)
        return samples

    def __len__(self) -> int:
        return self.size

    @overload
    def __getitem__(self, index: int) -> Mapping[str, Any]: ...

    @overload
    def __getitem__(self, index: slice) -> Sequence[Mapping[str, Any]]: ...

    def __getitem__(self, index: int | slice) -> Mapping[str, Any] | Sequence[Mapping[str, Any]]:
        return self._load()[index]

    def __iter__(self) -> Iterator[Mapping[str, Any]]:
        return iter(self._load())

    def __eq__(self, other: object) -> bool:
        if isinstance(other, StoredSamples) and (other.path, other.offset) == (self.path,
                                                                                self.offset):
            return True
        if not isinstance(other, Sequence) or isinstance(other, (str, bytes)):
            return NotImplemented
        return len(other) == self.size and list(self) == list(other)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"StoredSamples({str(self.path)!r}, offset={self.offset}, size={self.size})"

