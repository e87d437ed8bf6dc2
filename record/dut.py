"""The unit under test (:class:`Dut`): which arm a run measured and with what code, so a record
says what was tested, not only how it went.

The identity comes from the ``[dut]`` table of the bench config and the command line's
``--dut NAME`` and ``--meta KEY=VALUE`` (a flag wins over the file, key by key): the arm's
``name`` and ``serial`` number, the ``firmware_commit`` it runs and the lab's ``host_commit``,
plus free ``meta`` pairs. Every value is printable text of at most :data:`MAX_TEXT` characters;
anything else is a :class:`~armbench.drivers.model.settings.SettingsError` naming the key.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from armbench.drivers.model.settings import SettingsError
from armbench.record.fields import _obj, _opt_str, _str

__all__ = ["DUT_KEYS", "MAX_META", "MAX_TEXT", "Dut", "DutJson", "dut_flags", "parse_dut",
           "printable_text"]

#: The named keys of the ``[dut]`` table (``meta`` holds the free ones).
DUT_KEYS = ("name", "serial", "firmware_commit", "host_commit")
#: The longest value (characters) the unit's identity keeps.
MAX_TEXT = 200
#: The most free ``meta`` pairs a unit carries.
MAX_META = 32

_META_KEY = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")

#: The JSON object of a :class:`Dut` (``environment.dut`` of ``results.json``).
DutJson = dict[str, Any]


def _shown(value: object) -> object:
    """``value`` cut for an error message (a value of a megabyte is not printed whole)."""
    if isinstance(value, str) and len(value) > 60:
        return value[:60] + "…"
    return value


def printable_text(where: str, value: object, max_len: int = MAX_TEXT) -> str:
    """``value`` if it is printable text (no control characters) of 1 to ``max_len``
    characters, else a SettingsError naming ``where``."""
    if not isinstance(value, str):
        raise SettingsError(where, _shown(value), "is not a string")
    if not value:
        raise SettingsError(where, value, "is empty")
    if len(value) > max_len:
        raise SettingsError(where, _shown(value), f"is longer than {max_len} characters")
    if not value.isprintable():
        raise SettingsError(where, _shown(value), "holds characters that are not printable")
    return value


@dataclass(frozen=True, slots=True)
class Dut:
    """The unit under test: the arm's ``name`` and ``serial`` number, the ``firmware_commit`` it
    runs, the lab's ``host_commit``, and free ``meta`` pairs; every field may be unknown."""

    name: str | None = None
    serial: str | None = None
    firmware_commit: str | None = None
    host_commit: str | None = None
    meta: Mapping[str, str] = field(default_factory=dict)

    def __bool__(self) -> bool:
        return any(getattr(self, k) is not None for k in DUT_KEYS) or bool(self.meta)

    def items(self) -> list[tuple[str, str]]:
        """The known values as ``(key, value)``, the named keys first, then ``meta.<key>``."""
        named = [(k, v) for k in DUT_KEYS if (v := getattr(self, k)) is not None]
        return named + [(f"meta.{k}", v) for k, v in self.meta.items()]

    def label(self) -> str:
        """How people name the unit: ``"arm-3 (serial RL-0042)"``, ``"-"`` when unnamed."""
        if self.name is None and self.serial is None:
            return "-"
        if self.serial is None:
            return str(self.name)
        return f"{self.name or 'unnamed'} (serial {self.serial})"

    def with_flags(self, flags: Mapping[str, str]) -> Dut:
        """This identity with the values of :func:`dut_flags` over it, key by key."""
        named = {k: v for k, v in flags.items() if k in DUT_KEYS}
        meta = {**self.meta, **{k[5:]: v for k, v in flags.items() if k.startswith("meta.")}}
        if len(meta) > MAX_META:
            raise SettingsError("--meta", len(meta), f"gives more than {MAX_META} pairs")
        return replace(self, **named, meta=meta)

    def to_json(self) -> DutJson:
        """The JSON object of this identity."""
        return {**{k: getattr(self, k) for k in DUT_KEYS}, "meta": dict(self.meta)}

    @classmethod
    def from_json(cls, data: object, where: str) -> Dut:
        """Parse ``environment.dut``; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)
        meta = _obj(d.get("meta", {}), f"{where}.meta")
        return cls(**{k: _opt_str(d.get(k), f"{where}.{k}") for k in DUT_KEYS},
                   meta={str(k): _str(v, f"{where}.meta.{k}") for k, v in meta.items()})


def parse_dut(table: object) -> Dut:
    """The ``[dut]`` table of the bench config, checked: the named keys and a ``[dut.meta]``
    table of free pairs; anything else is a SettingsError naming the key."""
    if not isinstance(table, Mapping):
        raise SettingsError("dut", _shown(table), "is not a table")
    values: dict[str, str] = {}
    for key, value in table.items():
        if key == "meta":
            continue
        if key not in DUT_KEYS:
            raise SettingsError(f"dut.{key}", _shown(value), "is not a known key (known: "
                                f"{', '.join(DUT_KEYS)}, meta)")
        values[key] = printable_text(f"dut.{key}", value)
    meta_table = table.get("meta", {})
    if not isinstance(meta_table, Mapping):
        raise SettingsError("dut.meta", _shown(meta_table), "is not a table")
    if len(meta_table) > MAX_META:
        raise SettingsError("dut.meta", len(meta_table), f"holds more than {MAX_META} pairs")
    meta = {_meta_key(f"dut.meta.{key}", key): printable_text(f"dut.meta.{key}", value)
            for key, value in meta_table.items()}
    return Dut(**values, meta=meta)


def _meta_key(where: str, key: object) -> str:
    if not isinstance(key, str) or not _META_KEY.fullmatch(key):
        raise SettingsError(where, _shown(key), "is not a key (letters, digits, '_', '.', '-'; "
                                                "at most 64)")
    return key


def dut_flags(name: str | None, meta: Sequence[str]) -> dict[str, str]:
    """The identity the command line gives: ``--dut NAME`` and each ``--meta KEY=VALUE`` (a
    named key such as ``serial`` or ``firmware_commit`` sets that key, any other a free pair,
    ``meta.KEY``), checked; a key given twice is refused."""
    flags: dict[str, str] = {}
    if name is not None:
        flags["name"] = printable_text("--dut", name)
    for given in meta:
        key, sep, value = given.partition("=")
        if not sep:
            raise SettingsError("--meta", _shown(given), "is not KEY=VALUE")
        where = f"--meta {_shown(key)}"
        slot = key if key in DUT_KEYS else f"meta.{_meta_key(where, key)}"
        if slot in flags:
            raise SettingsError(where, _shown(value), "is given twice"
                                + (" (--dut gives the name)" if slot == "name" else ""))
        flags[slot] = printable_text(where, value)
    return flags

