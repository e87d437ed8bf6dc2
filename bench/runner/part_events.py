"""What a trial's connection writes into its capture part besides frames: the power switching
(:func:`logged_power`), the emulator's fault activations (:func:`fault_events`) and its ground
truth (:func:`emulator_truth`). A worker process uses these and never the run's MCAP writer
(:mod:`armbench.bench.runner.capture_run`), which it then does not import."""

from __future__ import annotations

import asyncio
from typing import Any

from armbench.bench.suites.base import PowerSwitch, ReReferencing
from armbench.drivers.capture.part import PartWriter
from armbench.drivers.transports.base import EmulatedTarget, Emulator, emulated

__all__ = ["LoggedPower", "LoggedReReferencingPower", "emulator_truth", "fault_events",
           "logged_power"]


class LoggedPower:
    """A power switch whose switching is written to a capture part as ``power_off`` /
    ``power_on`` events (loop time of the request)."""

    def __init__(self, inner: PowerSwitch, part: PartWriter, suite: str, trial: int) -> None:
        self.inner = inner
        self._part = part
        self._suite = suite
        self._trial = trial

    async def power_off(self) -> None:
        self._part.event(asyncio.get_running_loop().time(), "power_off", self._suite, self._trial)
        await self.inner.power_off()

    async def power_on(self) -> None:
        self._part.event(asyncio.get_running_loop().time(), "power_on", self._suite, self._trial)
        await self.inner.power_on()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.inner!r})"


class LoggedReReferencingPower(LoggedPower):
    """A :class:`LoggedPower` around a switch that can re-reference the arm (the emulator's, the
    firmware harness's): the capability stays (a wrapper without it made every stalled start-up
    recovery unrescuable while a capture was written), logged as ``re_reference``."""

    async def re_reference(self) -> None:
        inner = self.inner
        assert isinstance(inner, ReReferencing)  # logged_power chose this class for it
        self._part.event(asyncio.get_running_loop().time(), "re_reference", self._suite,
                         self._trial)
        await inner.re_reference()


def logged_power(inner: PowerSwitch, part: PartWriter, suite: str,
                 trial: int) -> LoggedPower:
    """``inner`` with its switching written to ``part``, its capabilities kept."""
    if isinstance(inner, ReReferencing):
        return LoggedReReferencingPower(inner, part, suite, trial)
    return LoggedPower(inner, part, suite, trial)


class _NewestTruth:
    """The newest ground truth (rad) of a target's emulator, read at each call (a simulator may
    make its emulator when opened); None before the first reply or without an emulator. The
    true angles (the links' angles and their deflection under gravity, computed when read) are
    computed again only when the links moved or the emulator changed: a resting arm costs a
    comparison."""

    def __init__(self, source: EmulatedTarget) -> None:
        self._source = source
        self._links: tuple[float, ...] | None = None
        self._emulator: Emulator | None = None
        self._true: tuple[float, ...] = ()

    def __call__(self) -> tuple[float, ...] | None:
        emulator = emulated(self._source)
        truth = () if emulator is None else emulator.truth
        if not truth:
            return None
        sample = truth[-1]
        if sample.link_rad != self._links or emulator is not self._emulator:
            self._links, self._emulator = sample.link_rad, emulator
            self._true = tuple(sample.true_rad)
        return self._true


def emulator_truth(source: EmulatedTarget | None) -> _NewestTruth | None:
    """A callable giving the newest ground truth (rad) of ``source``'s emulator (``source`` is a
    transport), for :class:`PartWriter`; None without a source."""
    return None if source is None else _NewestTruth(source)


def fault_events(emulator: Any, part: PartWriter | None) -> None:
    """The emulator's fault activations (``injector.activations``) as ``fault`` events."""
    injector = getattr(emulator, "injector", None)
    if injector is None or part is None:
        return
    for t_rel, description in getattr(injector, "activations", ()):
        part.event(injector.t_start + t_rel, "fault", detail={"fault": description})
