"""The JSON text of the record: strict JSON (no NaN) laid out for people and diffs, and the one
``default`` hook that turns the non-JSON values suites hand over (numpy, TOML dates) into JSON."""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator, Mapping
from datetime import date, datetime
from datetime import time as time_of_day
from json.encoder import c_make_encoder, encode_basestring  # type: ignore[attr-defined]
from typing import Any

from armbench.record.fields import RecordError

__all__ = ["Placeholder", "iter_encode", "json_default", "json_line"]


def json_default(obj: object) -> Any:
    """JSON for the non-JSON values suites commonly hand over: numpy arrays and scalars
    (``tolist``), TOML dates and times (ISO 8601)."""
    if isinstance(obj, (datetime, date, time_of_day)):
        return obj.isoformat()
    tolist = getattr(obj, "tolist", None)
    if callable(tolist):
        return tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


_SCALARS = (str, int, float, bool, type(None))
#: What the C encoder writes for a finite float and an int (``float.__repr__``, ``int.__repr__``).
_float_repr = float.__repr__
_int_repr = int.__repr__
#: A flat object is written on one line when it is at most this long (characters).
_INLINE_WIDTH = 120
#: Between the items of an object or list laid out over several lines.
_SEPARATOR = ",\n"


class Placeholder:
    """A part :func:`iter_encode` leaves to its caller (a trial the writer streams from disk):
    ``item`` is the caller's, ``level`` the indentation depth it is to be encoded at."""

    __slots__ = ("item", "level")

    def __init__(self, item: object) -> None:
        self.item = item
        self.level = 0


#: One encoder for every one-line part: ``json.dumps`` with these options would build a new
#: ``JSONEncoder`` per call, and the record makes one call per sample.
_compact_encoder = json.JSONEncoder(ensure_ascii=False, allow_nan=False, separators=(", ", ": "),
                                    default=json_default)
#: The C encoder behind it, made once: ``JSONEncoder.encode`` makes one per call, which costs
#: more than encoding a sample's value. Without a check for circular references: it only sees
#: scalars and flat containers (:func:`_encode` recurses into the others itself).
_c_encoder = None if c_make_encoder is None else c_make_encoder(
    None, json_default, encode_basestring, None, ": ", ", ", False, False, False)


def _compact(value: object) -> str:
    """One line of strict JSON for a scalar or a flat container (what ``_compact_encoder``
    writes)."""
    if type(value) is str:  # a key: what the encoder does with it, minus the encoder
        return encode_basestring(value)
    if _c_encoder is None:
        return _compact_encoder.encode(value)
    return "".join(_c_encoder(value, 0))


def _all_scalars(values: Iterable[object]) -> bool:
    """True when every value is a scalar (a loop, not a generator: once per sample's vector)."""
    for v in values:  # noqa: SIM110 (all() over a generator: a frame per value)
        if not isinstance(v, _SCALARS):
            return False
    return True


def _is_flat(values: Iterable[object]) -> bool:
    """True when every value is a scalar or a list of scalars (a sample, a limit, a vector)."""
    for v in values:
        if not (isinstance(v, _SCALARS)
                or (isinstance(v, (list, tuple)) and _all_scalars(v))):
            return False
    return True


def _encode(value: object, level: int = 0) -> str:
    """Strict JSON (no NaN) for people and diffs: nested containers indented one space per
    level; lists of scalars (``[x, y, z]``) and short flat objects (a sample) on one line.

    Unlike ``json.dumps(indent=...)``, which runs the pure-Python encoder over everything, the
    one-line parts go through the C encoder, and a scalar inside a container is written where
    it is met (:func:`_item`): a record is mostly scalars, one call each was most of its cost.
    """
    if isinstance(value, _SCALARS):
        return _compact(value)
    if isinstance(value, Mapping):
        if not value:
            return "{}"
        if _is_flat(value.values()):
            text = _compact(value)
            if len(text) <= _INLINE_WIDTH:
                return text
        pad = " " * (level + 1)
        lines = [f"{pad}{encode_basestring(str(k))}: {_item(v, level + 1)}"
                 for k, v in value.items()]
        return "{\n" + ",\n".join(lines) + "\n" + " " * level + "}"
    if isinstance(value, (list, tuple)):
        if not value:
            return "[]"
        if _all_scalars(value):
            return _compact(value)
        pad = " " * (level + 1)
        lines = [f"{pad}{_item(v, level + 1)}" for v in value]
        return "[\n" + ",\n".join(lines) + "\n" + " " * level + "]"
    return _encode(json_default(value), level)


def _item(value: object, level: int) -> str:
    """:func:`_encode` of an item of a container: the common scalars by their exact type
    (what the C encoder writes for them), anything else (a NaN too) by :func:`_encode`."""
    if type(value) is str:
        return encode_basestring(value)
    if type(value) is float and value - value == 0.0:  # finite
        return _float_repr(value)
    if type(value) is int:
        return _int_repr(value)
    if value is None:
        return "null"
    if type(value) is bool:
        return "true" if value else "false"
    return _encode(value, level)


def _to_json_text(value: object, where: str, level: int = 0) -> str:
    """:func:`_encode` with errors (NaN, unknown types) as a RecordError naming ``where``."""
    try:
        return _encode(value, level)
    except (TypeError, ValueError) as exc:
        raise RecordError(where, f"cannot be stored as JSON: {exc} (NaN and infinity are not "
                                 "JSON; use null or leave the value out)") from None



def iter_encode(value: object, level: int = 0) -> Iterator[str | Placeholder]:
    """:func:`_encode` in pieces, for a file written as it is encoded: the same text, with each
    :class:`Placeholder` handed back (its ``level`` set) for the caller to encode in its place."""
    if isinstance(value, Placeholder):
        value.level = level
        yield value
        return
    if isinstance(value, (Mapping, list, tuple)) and value:
        pad = " " * (level + 1)
        if isinstance(value, Mapping):
            if _is_flat(value.values()) and len(text := _compact(value)) <= _INLINE_WIDTH:
                yield text
                return
            yield "{\n"
            for i, (k, v) in enumerate(value.items()):
                yield f"{_SEPARATOR if i else ''}{pad}{_compact(str(k))}: "
                yield from iter_encode(v, level + 1)
            yield "\n" + " " * level + "}"
            return
        if not _all_scalars(value):
            yield "[\n"
            for i, v in enumerate(value):
                yield f"{_SEPARATOR if i else ''}{pad}"
                yield from iter_encode(v, level + 1)
            yield "\n" + " " * level + "]"
            return
    if isinstance(value, (*_SCALARS, Mapping, list, tuple)):
        yield _encode(value, level)
        return
    yield from iter_encode(json_default(value), level)


def json_line(value: object, where: str) -> str:
    """``value`` as one line of compact strict JSON (a journal entry, ending in a newline);
    errors as a RecordError naming ``where``."""
    try:
        text = json.dumps(value, ensure_ascii=False, allow_nan=False, separators=(",", ":"),
                          default=json_default)
    except (TypeError, ValueError) as exc:
        raise RecordError(where, f"cannot be stored as JSON: {exc} (NaN and infinity are not "
                                 "JSON; use null or leave the value out)") from None
    return text + "\n"
