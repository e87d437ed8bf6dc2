"""What a bench suite is, and what the runner hands it.

A suite plans its trials from its parameters, runs one trial at a time against the arm (any port:
``fake://``, a pty, TCP, RFC 2217, a real serial port), and reduces the finished trials to
suite-level measurements. The runner writes every finished trial to disk before the next begins,
so a suite never keeps results only in memory; a resumed run calls ``run_trial`` only for the
trials the record does not have yet.

Time: suites read time only from the running event loop (``loop.time()``) and wait only with
asyncio, so the same suite runs on virtual time against the emulator and in real time against
hardware.
"""

from __future__ import annotations

import abc
import random
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, runtime_checkable

from armbench.drivers.model.settings import RobotSettings
from armbench.record import Better, Measurement, Trial, judge
from armbench.record.limits import LimitsConfig

if TYPE_CHECKING:
    from armbench.drivers.host.arm import Arm

__all__ = ["PoseSource", "PowerSwitch", "Progress", "ReReferencing", "Suite", "SuiteContext"]


class PowerSwitch(Protocol):
    """Cuts and restores the arm's power: the emulator's power control for ``fake://``; for
    hardware a configured command (a relay script) or a prompt to the operator."""

    async def power_off(self) -> None:
        """Cut the power now."""

    async def power_on(self) -> None:
        """Restore the power now."""


@runtime_checkable
class ReReferencing(Protocol):
    """A power switch that can also re-reference the arm while its power is off (the emulator's,
    the firmware harness's): what a lab does by hand to an arm whose start-up recovery stalled
    (re-home the joints, erase the EEPROMs). A relay or an operator prompt cannot."""

    async def re_reference(self) -> None:
        """Make the arm's stored position agree with where it stands (power off)."""


class PoseSource(Protocol):
    """Where a measured position comes from besides the firmware's own report.

    ``true_position_m`` returns the TCP position (m, base frame) a reference instrument sees now:
    the emulator's ground truth over ``fake://``, or a plug-in for a laser tracker on hardware;
    ``None`` when no such instrument exists (then only forward kinematics of the reported joints is
    recorded, as the paper did).
    """

    def true_position_m(self) -> tuple[float, float, float] | None:
        """The instrument's TCP position now, metres."""
        ...

    def true_joints_rad(self) -> tuple[float, ...] | None:
        """The instrument's joint angles now (protocol convention), radians, if it has them."""
        ...


Progress = Callable[[str], None]
"""Receives one-line progress messages (suite, trial k of n, elapsed and remaining time)."""


@dataclass(slots=True)
class SuiteContext:
    """Everything a suite may use: the connected arm and the bench around it."""

    arm: Arm
    settings: RobotSettings
    limits: LimitsConfig
    params: Mapping[str, Any]
    rng: random.Random
    power: PowerSwitch | None = None
    truth: PoseSource | None = None
    progress: Progress = field(default=lambda message: None)
    artifacts: Callable[[str], Any] | None = None
    """``artifacts(name)`` → a path inside the run directory for a suite's extra files."""

    def judge(self, name: str, value: float, unit: str, *, better: Better | None = None,
              description: str = "") -> Measurement:
        """A measurement judged against the configured limits (reported, not judged, without)."""
        return judge(name, value, unit, self.limits, better=better, description=description)


class Suite(abc.ABC):
    """One bench suite: plan trials, run each against the arm, summarise."""

    name: str = ""
    """The suite's name on the command line and in the record (``accuracy``, ...)."""
    version: str = "1"
    """Bumped when the suite's procedure changes (a baseline of another version is refused)."""
    metric_units: ClassVar[Mapping[str, str]] = {}
    """The unit of each metric the suite records, by ``fnmatch`` pattern of its name: the runner
    checks the limits file against them before any motion (undeclared metrics are checked when
    judged)."""

    @abc.abstractmethod
    def default_params(self, settings: RobotSettings) -> dict[str, Any]:
        """Parameters when the config gives none (must be reachable within the joint limits)."""

    def params(self, settings: RobotSettings, configured: Mapping[str, Any]) -> dict[str, Any]:
        """Defaults overridden by the config's ``[suites.<name>]`` table; unknown keys refused;
        validated."""
        params = self.configured_params(settings, configured)
        self.validate(settings, params)
        return params

    def configured_params(self, settings: RobotSettings,
                          configured: Mapping[str, Any]) -> dict[str, Any]:
        """Defaults overridden by the config's ``[suites.<name>]`` table, unknown keys refused,
        not validated: what the config check reads the metric names of a suite not run with."""
        from armbench.drivers.model.settings import SettingsError

        params = self.default_params(settings)
        for key, value in configured.items():
            if key not in params:
                raise SettingsError(f"suites.{self.name}.{key}", value,
                                    f"is not a parameter of {self.name} "
                                    f"(known: {', '.join(sorted(params))})")
            params[key] = value
        return params

    def validate(self, settings: RobotSettings,  # noqa: B027 (an optional hook)
                 params: Mapping[str, Any]) -> None:
        """Raise ``SettingsError`` naming the field for an invalid parameter (before any motion)."""

    @abc.abstractmethod
    def metric_names(self, params: Mapping[str, Any]) -> frozenset[str]:
        """Every metric name the suite can record with ``params``: its trials' and its
        summary's, the figures of a bench with a reference instrument (``true_``, ``belief_``)
        included. Before any motion the runner refuses a limit or tolerance pattern of the
        config that matches no name of any suite (``docs/record.md``); a suite derives the names
        from its contract, as it makes them, so the two cannot drift."""

    @abc.abstractmethod
    def plan(self, params: Mapping[str, Any]) -> Sequence[Mapping[str, Any]]:
        """The trials to run, as their parameters, in order (index = position)."""

    @abc.abstractmethod
    def run_trial(self, ctx: SuiteContext, index: int,
                  trial_params: Mapping[str, Any]) -> Awaitable[Trial]:
        """Run one trial and return it (``status="error"`` when it could not be measured)."""

    def emulated_settings(self, settings: RobotSettings,
                          trial_params: Mapping[str, Any]) -> RobotSettings:
        """The arm the emulator plays in a ``fake://`` trial: ``settings`` (the bench's model of
        the arm, which the driver keeps); a campaign draws another arm per trial."""
        return settings

    @abc.abstractmethod
    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        """Suite-level measurements from all finished trials (what baselines compare)."""
