"""Measurement sources: where a suite gets the TCP position an external instrument sees.

:class:`~armbench.bench.suites.base.PoseSource` is the interface; here are its sources:

- :class:`EmulatorTruth` — ``fake://``: the emulator's ground truth (the real joint angles,
  backlash and lost steps included, which the firmware's encoders do not see), through forward
  kinematics (:func:`armbench.drivers.model.kinematics.tcp_position`);
- a plug-in for hardware: ``--tracker package.module:Class`` loads a class implementing
  ``PoseSource`` (a laser tracker or camera driver), see :func:`load_tracker`;
- ``None`` when there is neither: suites then record only the forward kinematics of the joints
  the firmware reports.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Mapping
from typing import Any

from armbench.bench.suites.base import PoseSource
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.kinematics import tcp_position
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.transports.base import EmulatedTarget, Emulator

__all__ = ["EmulatorTruth", "TrackerError", "aclose_source", "aopen_source", "load_tracker"]


class TrackerError(ArmbenchError, ValueError):
    """A ``--tracker`` plug-in cannot be loaded or does not implement ``PoseSource``."""


class EmulatorTruth:
    """Ground truth of the ``fake://`` emulator as a :class:`PoseSource`.

    ``source`` is an :class:`~armbench.drivers.transports.base.EmulatedTarget` (an
    :class:`~armbench.drivers.host.arm.Arm` or a fake transport, whose emulator is read at every
    call so a reconnection is followed), or the emulator itself.
    :meth:`true_joints_rad` are the real joint angles now (``emulator.true_angles_rad()``);
    :meth:`true_position_m` is their forward kinematics (m, base frame) with ``settings`` (the
    arm's own settings when None).
    """

    def __init__(self, source: EmulatedTarget | Emulator,
                 settings: RobotSettings | None = None) -> None:
        self._source = source
        self._settings = settings
        # which of the two ``source`` is, decided once: a protocol check costs microseconds
        self._target: EmulatedTarget | None = None
        self._own: Emulator | None = None
        if isinstance(source, EmulatedTarget):
            self._target = source
        else:
            self._own = source

    @property
    def settings(self) -> RobotSettings:
        """The robot model used for forward kinematics."""
        if self._settings is not None:
            return self._settings
        own = getattr(self._source, "settings", None)
        return own if isinstance(own, RobotSettings) else RobotSettings()

    def _emulator(self) -> Emulator | None:
        return self._own if self._target is None else self._target.emulator

    def true_joints_rad(self) -> tuple[float, ...] | None:
        """The real joint angles now (rad, protocol convention), None without an emulator."""
        emulator = self._emulator()
        if emulator is None:
            return None
        return tuple(float(q) for q in emulator.true_angles_rad())

    def true_position_m(self) -> tuple[float, float, float] | None:
        """The real TCP position now (m, base frame), None without an emulator: the emulator's
        own (its actual kinematics) unless ``settings`` were given."""
        emulator = self._emulator()
        if emulator is not None and self._settings is None:
            x, y, z = emulator.true_position_m()
            return float(x), float(y), float(z)
        q = self.true_joints_rad()
        if q is None:
            return None
        p = tcp_position(q, self.settings)
        return float(p[0]), float(p[1]), float(p[2])

    def __repr__(self) -> str:
        return "EmulatorTruth()"


def load_tracker(spec: str, settings: RobotSettings,
                 params: Mapping[str, Any] | None = None) -> PoseSource:
    """Load and create the ``--tracker`` plug-in ``"package.module:Class"``.

    The class is called as ``Class(settings=settings, **params)`` when its constructor accepts a
    ``settings`` argument (``params`` being the ``[bench.tracker]`` table of the bench config),
    else ``Class(**params)``. The instance must have ``true_position_m()`` and
    ``true_joints_rad()``; optional ``async open()`` / ``async close()`` are awaited by the runner
    around the run. Every problem raises :class:`TrackerError` naming ``--tracker``.
    """
    module_name, sep, class_name = spec.partition(":")
    if not (sep and module_name and class_name):
        raise TrackerError(f"--tracker: {spec!r} is not package.module:Class")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise TrackerError(f"--tracker: module {module_name} cannot be imported: {exc}") from exc
    cls = getattr(module, class_name, None)
    if not callable(cls):
        raise TrackerError(f"--tracker: {spec} is not a class")
    kwargs = dict(params or {})
    try:
        accepts_settings = "settings" in inspect.signature(cls).parameters
    except (TypeError, ValueError):
        accepts_settings = False
    if accepts_settings:
        kwargs["settings"] = settings
    try:
        source = cls(**kwargs)
    except Exception as exc:
        raise TrackerError(f"--tracker: {spec}({', '.join(kwargs)}) failed: {exc}") from exc
    for method in ("true_position_m", "true_joints_rad"):
        if not callable(getattr(source, method, None)):
            raise TrackerError(f"--tracker: {spec} has no method {method}() (PoseSource needs "
                               "true_position_m and true_joints_rad)")
    loaded: PoseSource = source
    return loaded


async def aopen_source(source: object) -> None:
    """Await ``source.open()`` if the source has one (a tracker connecting to its instrument)."""
    await _maybe_await(getattr(source, "open", None))


async def aclose_source(source: object) -> None:
    """Await ``source.close()`` if the source has one."""
    await _maybe_await(getattr(source, "close", None))


async def _maybe_await(method: Callable[[], Any] | None) -> None:
    if not callable(method):
        return
    result = method()
    if inspect.isawaitable(result):
        await result
