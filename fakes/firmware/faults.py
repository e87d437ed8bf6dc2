"""Fault injection for the emulator: faults are data, scheduled by time or by event, seeded.

A fault list comes from TOML (``[[faults]]`` tables in a settings or faults file) or a
``fake://?faults=FILE`` query. The same list and seed reproduce the same run: every random choice
comes from one ``random.Random(seed)`` drawn in event order.

=================  ===========================================================================
kind               effect while active
=================  ===========================================================================
uart_corrupt       each byte (``direction``) is altered with ``probability``
uart_drop          each byte is lost with ``probability``
uart_insert        ``count`` random bytes are inserted into a chunk with ``probability``
split_write        a chunk to the host arrives in ``count + 1`` pieces ``delay_s`` apart
delay_write        chunks to the host arrive ``delay_s`` late
i2c_nak            the slave of ``joint`` (all slaves if unset) does not acknowledge
i2c_bus_error      transactions to ``joint``'s slave fail with a bus error (EIO)
slave_reset        board ``joint`` reboots once (RAM lost, start-up procedure runs)
stall              joint ``joint`` is mechanically blocked for ``duration_s`` (forever if unset)
power_cut          the whole arm loses power (EEPROM and mechanics survive)
power_restore      power comes back
=================  ===========================================================================

Timing: ``at_s`` (seconds after the emulator started) or ``after_frames`` (when the master has
received that many command frames); window faults last ``duration_s`` (forever if unset).
"""

from __future__ import annotations

import asyncio
import errno
import itertools
import random
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Literal, Protocol, get_args

from armbench.drivers.model.bounds import Bound, check, check_whole
from armbench.drivers.model.settings import RobotSettings, SettingsError, read_toml

__all__ = ["FAULT_KINDS", "Fault", "FaultInjector", "faults_from_settings", "load_faults",
           "parse_faults"]

FaultKind = Literal["uart_corrupt", "uart_drop", "uart_insert", "split_write", "delay_write",
                    "i2c_nak", "i2c_bus_error", "slave_reset", "stall", "power_cut",
                    "power_restore"]
FAULT_KINDS: tuple[str, ...] = get_args(FaultKind)
_UART = {"uart_corrupt", "uart_drop", "uart_insert", "split_write", "delay_write"}
_ONE_SHOT = {"slave_reset", "power_cut", "power_restore"}


@dataclass(frozen=True, slots=True)
class Fault:
    """One scheduled fault; see the module docstring for the kinds."""

    kind: FaultKind
    at_s: float | None = None
    after_frames: int | None = None
    duration_s: float | None = None
    joint: int | None = None
    probability: float = 1.0
    count: int = 1
    delay_s: float = 0.0
    direction: Literal["to_host", "to_robot"] = "to_host"

    def describe(self) -> str:
        """One line for logs and reports."""
        when = f"at {self.at_s:g} s" if self.at_s is not None else (
            f"after {self.after_frames} frames")
        extra = f" for {self.duration_s:g} s" if self.duration_s is not None else ""
        who = f" joint {self.joint}" if self.joint is not None else ""
        return f"{self.kind}{who} {when}{extra}"


#: The bounds of a fault's numbers: its times, frame count, probability, repeats and joint.
_SECONDS = Bound(0.0, 1e6, "s")
_FRAMES = Bound(1, 1e9, "frames", whole=True)
_PROBABILITY = Bound(0.0, 1.0)
_COUNT = Bound(1, 1024, whole=True)
_JOINT = Bound(1, 4, whole=True)


def parse_faults(items: Iterable[Mapping[str, Any]], where: str = "faults") -> list[Fault]:
    """Validated faults from TOML-shaped tables; errors name the entry and field."""
    out: list[Fault] = []
    known = {f.name for f in fields(Fault)}
    for i, item in enumerate(items):
        path = f"{where}[{i}]"
        if not isinstance(item, Mapping):
            raise SettingsError(path, item, "is not a table")
        for k, v in item.items():
            if k not in known:
                raise SettingsError(f"{path}.{k}", v, "is not a known fault field")
        kind = item.get("kind")
        if kind not in FAULT_KINDS:
            raise SettingsError(f"{path}.kind", kind, f"is not one of {', '.join(FAULT_KINDS)}")
        try:
            fault = Fault(**item)
        except TypeError as exc:
            raise SettingsError(path, dict(item), str(exc)) from None
        if (fault.at_s is None) == (fault.after_frames is None):
            raise SettingsError(path, dict(item), "needs exactly one of at_s or after_frames")
        for name in ("at_s", "duration_s", "delay_s"):
            v = getattr(fault, name)
            if v is not None:
                check(f"{path}.{name}", v, _SECONDS)
        if fault.after_frames is not None:
            check_whole(f"{path}.after_frames", fault.after_frames, _FRAMES)
        check(f"{path}.probability", fault.probability, _PROBABILITY)
        check_whole(f"{path}.count", fault.count, _COUNT)
        if fault.joint is not None:
            check_whole(f"{path}.joint", fault.joint, _JOINT)
        if fault.kind in ("i2c_nak", "i2c_bus_error") and fault.joint == 1:
            raise SettingsError(f"{path}.joint", 1, "is the I²C master; slaves are 2..4")
        if fault.kind in ("slave_reset", "stall") and fault.joint is None:
            raise SettingsError(f"{path}.joint", None, f"is required for {fault.kind}")
        if fault.direction not in ("to_host", "to_robot"):
            raise SettingsError(f"{path}.direction", fault.direction,
                                "must be 'to_host' or 'to_robot'")
        out.append(fault)
    return out


def load_faults(path: str | Path) -> list[Fault]:
    """Faults from a TOML file of ``[[faults]]`` tables. Any other table or key is refused (a
    misspelt ``[[faultz]]``, a limits file given by mistake), and so is a file with no fault:
    either would run with no faults injected and pass."""
    p = Path(path)
    data = read_toml(p, "faults")
    for key in data:
        if key != "faults":
            raise SettingsError(f"faults file {p}", key, "is not a table of a faults file "
                                                         "(it holds [[faults]] tables only)")
    items = data.get("faults", [])
    if not isinstance(items, list):
        raise SettingsError("faults", items, "must be an array of tables ([[faults]])")
    if not items:
        raise SettingsError("faults", str(p), "holds no [[faults]] table: nothing to inject")
    return parse_faults(items)


def faults_from_settings(robot: RobotSettings) -> list[Fault]:
    """The ``[[faults]]`` tables of a robot settings file (none if it has none)."""
    items = robot.sections.get("faults", [])
    if not isinstance(items, list):
        raise SettingsError("faults", items, "must be an array of tables ([[faults]])")
    return parse_faults(items)


class FaultTarget(Protocol):
    """What the injector acts on (the arm)."""

    def reset_board(self, joint: int) -> None:
        """Reboot one board."""

    def set_stalled(self, joint: int, stalled: bool) -> None:
        """Block or free a joint."""

    def power_off(self) -> None:
        """Cut the arm's power."""

    def power_on(self) -> None:
        """Restore the arm's power."""

    def slave_address(self, joint: int) -> int:
        """The I²C address of a slave joint."""
        ...


class FaultInjector:
    """Activates faults at their time or event and answers the hooks of the UART and bus."""

    def __init__(self, faults: Sequence[Fault], seed: int, target: FaultTarget) -> None:
        self.faults = list(faults)
        self.rng = random.Random(seed)
        self.target = target
        self._active: dict[int, float] = {}  # fault index -> end time (inf: forever)
        self._handles: list[asyncio.TimerHandle] = []
        self.t_start = 0.0
        self.activations: list[tuple[float, str]] = []
        """(time, description) of every activation, for the record."""

    def start(self, t_s: float) -> None:
        """Schedule the time-based faults relative to ``t_s``."""
        self.t_start = t_s
        loop = asyncio.get_running_loop()
        for i, f in enumerate(self.faults):
            if f.at_s is None:
                continue
            if f.at_s <= 0:  # before the boards' first step, so not even one loop escapes it
                self._activate(i)
            else:
                self._handles.append(loop.call_at(t_s + f.at_s, self._activate, i))

    def stop(self) -> None:
        """Cancel what has not happened yet."""
        for h in self._handles:
            h.cancel()
        self._handles.clear()

    def on_command(self, count: int) -> None:
        """The master has received its ``count``-th command frame."""
        for i, f in enumerate(self.faults):
            if f.after_frames == count:
                self._activate(i)

    def _activate(self, i: int) -> None:
        f = self.faults[i]
        now = asyncio.get_running_loop().time()
        self.activations.append((now - self.t_start, f.describe()))
        if f.kind == "power_cut":
            self.target.power_off()
        elif f.kind == "power_restore":
            self.target.power_on()
        elif f.kind == "slave_reset":
            assert f.joint is not None
            self.target.reset_board(f.joint)
        elif f.kind == "stall":
            assert f.joint is not None
            self.target.set_stalled(f.joint, True)
            if f.duration_s is not None:
                joint = f.joint
                self._handles.append(asyncio.get_running_loop().call_at(
                    now + f.duration_s, self.target.set_stalled, joint, False))
        if f.kind not in _ONE_SHOT:
            self._active[i] = now + f.duration_s if f.duration_s is not None else float("inf")

    def _live(self, t_s: float, kinds: set[str]) -> Iterable[Fault]:
        for i, end in list(self._active.items()):
            if t_s >= end:
                del self._active[i]
                continue
            f = self.faults[i]
            if f.kind in kinds:
                yield f

    # hooks -------------------------------------------------------------------------------------
    def i2c_fault(self, address: int, t_s: float) -> int:
        """Bus hook: an errno for a transaction to ``address`` at ``t_s``, 0 for none."""
        for f in self._live(t_s, {"i2c_nak", "i2c_bus_error"}):
            if f.joint is None or self.target.slave_address(f.joint) == address:
                return errno.EREMOTEIO if f.kind == "i2c_nak" else errno.EIO
        return 0

    def to_robot(self, data: bytes, t_s: float) -> bytes:
        """UART hook: what a host write turns into on its way to the master."""
        for f in self._live(t_s, _UART):
            if f.direction == "to_robot":
                data = self._mangle(f, data)
        return data

    def to_host(self, data: bytes, t_s: float) -> list[tuple[float, bytes]]:
        """UART hook: how a chunk to the host is altered, cut and delayed."""
        pieces: list[tuple[float, bytes]] = [(0.0, data)]
        for f in self._live(t_s, _UART):
            if f.direction != "to_host":
                continue
            if f.kind == "delay_write":
                pieces = [(d + f.delay_s, c) for d, c in pieces]
            elif f.kind == "split_write":
                pieces = [p for d, c in pieces for p in self._split(f, d, c)]
            else:
                pieces = [(d, self._mangle(f, c)) for d, c in pieces]
        return [(d, c) for d, c in pieces if c]

    def _split(self, f: Fault, delay: float, chunk: bytes) -> list[tuple[float, bytes]]:
        if len(chunk) < 2 or self.rng.random() >= f.probability:
            return [(delay, chunk)]
        cuts = sorted(self.rng.sample(range(1, len(chunk)), min(f.count, len(chunk) - 1)))
        bounds = [0, *cuts, len(chunk)]
        return [(delay + k * f.delay_s, chunk[a:b])
                for k, (a, b) in enumerate(itertools.pairwise(bounds))]

    def _mangle(self, f: Fault, data: bytes) -> bytes:
        rng = self.rng
        if f.kind == "uart_corrupt":
            out = bytearray(data)
            for i in range(len(out)):
                if rng.random() < f.probability:
                    out[i] ^= rng.randrange(1, 256)
            return bytes(out)
        if f.kind == "uart_drop":
            return bytes(b for b in data if rng.random() >= f.probability)
        if f.kind == "uart_insert" and rng.random() < f.probability:
            at = rng.randrange(len(data) + 1)
            return data[:at] + bytes(rng.randrange(256) for _ in range(f.count)) + data[at:]
        return data
