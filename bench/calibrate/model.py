"""What a calibration measures and what it concludes: the observations (JSON-ready, written to disk
as they grow), the fitted parameters, and the typed errors of a calibration.

Observations keep raw figures only (angles in rad, times in s), so a fit can be repeated from the
file alone (``armbench calibrate --observations``) and a partial run keeps what it measured.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

from armbench.drivers.model.errors import ArmbenchError

if TYPE_CHECKING:
    from armbench.drivers.model.settings import RobotSettings

__all__ = [
    "APPROACH_OFFSET_RAD",
    "NO_TRUTH",
    "Approach",
    "ArmDoesNotMoveError",
    "CalibrationError",
    "CalibrationResult",
    "CaptureContentError",
    "Fitted",
    "HeldOut",
    "Hold",
    "Observations",
    "PageRenderer",
    "ReferencePose",
    "SpeedRun",
    "no_truth",
    "run_sigma",
    "session_scatter",
]


#: Distance (rad) each ISO 230-2 approach starts from its target: beyond the widest gear play of
#: the documented range and across the Hall sensor's position error.
APPROACH_OFFSET_RAD: Final = 0.04


class CalibrationError(ArmbenchError):
    """A calibration cannot be made (bad input, nothing to fit)."""


class ArmDoesNotMoveError(CalibrationError):
    """A joint did not follow a command: stalled, blocked or unpowered. ``joint`` is 1..4; what
    was measured before is kept (``partial``)."""

    def __init__(self, joint: int, target_rad: float, reached_rad: float, phase: str) -> None:
        super().__init__(f"joint {joint} does not move: commanded to {target_rad:+.4f} rad during "
                         f"the {phase} phase, it stayed at {reached_rad:+.4f} rad (stalled or "
                         "blocked?); what was measured before is kept")
        self.joint = joint
        self.target_rad = target_rad
        self.reached_rad = reached_rad
        self.phase = phase


class CaptureContentError(CalibrationError, ValueError):
    """A capture cannot be used: truncated, of another robot model, or without commands; names the
    file and the problem."""

    def __init__(self, path: str, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = path
        self.problem = problem


@dataclass(slots=True)
class Approach:
    """One ISO 230-2 approach: ``joint`` (1..4) came to ``target_rad`` moving ``direction`` (±1)
    at ``duty``; the reply and, with a truth source, the true joints (``true_rad``: deflection
    included), the link angles before deflection (``link_rad``) and the motor shafts
    (``motor_rad``) at rest."""

    joint: int
    target_rad: float
    direction: int
    duty: int
    reported_rad: list[float]
    true_rad: list[float] | None = None
    link_rad: list[float] | None = None
    motor_rad: list[float] | None = None
    firmware_rad: list[float] | None = None
    cycle: int = 0


@dataclass(slots=True)
class Hold:
    """The arm at rest at a pose of some gravity load, every joint approached moving ``+``: the
    reply, the true joints and TCP (m) when a truth source exists (and the link angles before
    deflection when it has them)."""

    reported_rad: list[float]
    true_rad: list[float] | None = None
    motor_rad: list[float] | None = None
    tcp_true_m: list[float] | None = None
    link_rad: list[float] | None = None


@dataclass(slots=True)
class SpeedRun:
    """One move of one joint at ``duty`` towards ``direction`` from ``start_rad`` (all joints):
    the speed law (12) predicts ``law_rad_s``; the replies gave ``rate_rad_s`` (slope over the
    middle of the move, ``samples`` replies) and ``steps`` microsteps were travelled.
    ``rate_sigma_rad_s``: the slope's standard error from the scatter of those replies about it
    (the link's and the host's timing jitter included: the arm's own noise)."""

    joint: int
    duty: int
    direction: int
    start_rad: list[float]
    law_rad_s: float
    rate_rad_s: float
    samples: int
    steps: float
    rate_sigma_rad_s: float | None = None

    @property
    def ratio(self) -> float:
        """Effective over commanded speed (1 − the share of lost steps)."""
        return self.rate_rad_s / self.law_rad_s


@dataclass(slots=True)
class ReferencePose:
    """A pose where a lab measured the tool position (``bench/calibrate/reference.py``): the
    joint angles (rad, protocol convention: the reported ones), the tool position measured (m,
    base frame) and its standard error per coordinate (m), the direction each joint last moved
    in to get there (±1) and, from a touch-off, its reported angles after each move since the
    move that brought it there (the path the play operator replays), and where it came from."""

    q_rad: list[float]
    xyz_m: list[float]
    sigma_m: float
    approach: list[int]
    history_rad: list[list[float]] | None = None
    source: str = ""


@dataclass(slots=True)
class HeldOut:
    """A held-out block of the session (``bench/calibrate/held_out_moves.py``): its name
    (``suite``: after the approaches, ``end``: at the end of the session), its window on the
    session capture's clock (s) and how many edges of the square it streamed."""

    name: str
    start_s: float
    end_s: float
    edges: int = 0


@functools.cache
def _field_names(kind: type) -> tuple[str, ...]:
    return tuple(f.name for f in fields(kind))


def _json_ready(value: Any) -> Any:
    """``value`` with its dataclasses as dicts and its containers new (``asdict``'s result):
    the numbers and strings, which never change, are not copied."""
    kind = type(value)
    if is_dataclass(kind):
        return {name: _json_ready(getattr(value, name)) for name in _field_names(kind)}
    if kind is list:
        return [_json_ready(v) for v in value]
    if kind is tuple:
        return tuple(_json_ready(v) for v in value)
    if kind is dict:
        return {k: _json_ready(v) for k, v in value.items()}
    return value


@dataclass(slots=True)
class Observations:
    """Everything one calibration measured, in the order it was measured."""

    source: str
    truth: bool = False
    motor_truth: bool = False
    reply_dt_s: list[float] = field(default_factory=list)
    latency_s: list[float] = field(default_factory=list)
    approaches: list[Approach] = field(default_factory=list)
    holds: list[Hold] = field(default_factory=list)
    speeds: list[SpeedRun] = field(default_factory=list)
    stalls: list[dict[str, Any]] = field(default_factory=list)
    held_out: list[HeldOut] = field(default_factory=list)
    #: Tool positions a lab measured (``--reference``) or touched (``--touch-off``).
    references: list[ReferencePose] = field(default_factory=list)
    #: The session's capture (every frame in and out), where the held-out blocks are.
    capture: str | None = None
    phases_done: list[str] = field(default_factory=list)
    phases_skipped: dict[str, str] = field(default_factory=dict)
    robot_time_s: float = 0.0
    error: str | None = None

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready mapping: what ``dataclasses.asdict`` gives, at a fraction of its cost
        (it copies every number; the observations are saved after every unit of work)."""
        out: dict[str, Any] = _json_ready(self)
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Observations:
        """The inverse of :meth:`to_json`."""
        d = dict(data)
        d["approaches"] = [Approach(**a) for a in d.get("approaches", [])]
        d["holds"] = [Hold(**h) for h in d.get("holds", [])]
        d["speeds"] = [SpeedRun(**s) for s in d.get("speeds", [])]
        d["held_out"] = [HeldOut(**b) for b in d.get("held_out", [])]
        d["references"] = [ReferencePose(**r) for r in d.get("references", [])]
        return cls(**d)

    def save(self, path: Path) -> None:
        """Write to ``path`` (replaced atomically, so a crash never leaves half a file)."""
        tmp = path.with_name(path.name + ".tmp")
        # one line: the indented form is written by json's Python encoder, three times slower
        tmp.write_text(json.dumps(self.to_json()) + "\n", encoding="utf-8")
        tmp.replace(path)


@dataclass(frozen=True, slots=True)
class Fitted:
    """One parameter of the robot model after the fit.

    ``key``: its dotted path in the settings file (``emulator.physics.j2.backlash_deg``);
    ``value`` and ``sigma`` (one standard error) in ``unit``; ``identified``: whether the data
    determined it (else ``value`` is the prior kept, and ``reason`` says why); ``reason`` also
    says what determined it. ``lower_bound``: what the data do say about a parameter they did not
    determine (``value`` is then raised to be consistent with it, and written). ``choice``: the
    value of a categorical parameter (a step-loss law), written instead of ``value``.
    """

    key: str
    value: float
    sigma: float | None
    unit: str
    identified: bool
    reason: str
    prior: float | None = None
    lower_bound: float | None = None
    choice: str | None = None

    @property
    def written(self) -> bool:
        """Whether the settings file gets this value (identified, or raised to a bound)."""
        return self.identified or self.lower_bound is not None

    def covers(self, truth: float, k: float = 2.0) -> bool:
        """Whether ``truth`` lies within ``k`` standard errors of the value (2: 95 %)."""
        if self.sigma is None or not math.isfinite(self.sigma):
            return False
        return abs(self.value - truth) <= k * self.sigma

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready mapping."""
        return asdict(self)


#: What a calibration without a reference instrument cannot tell (the header and the page say it).
@dataclass(frozen=True, slots=True)
class SensitivityRow:
    """One assumption: its name, its range as text and one cell per headline figure."""

    name: str
    range: str
    cells: list[str]


@dataclass(frozen=True, slots=True)
class Sensitivity:
    """The headline figures (keys) and one row per assumption; without rows, ``note`` says why
    there is nothing to show."""

    keys: list[str]
    rows: list[SensitivityRow]
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready mapping."""
        return {"keys": self.keys, "note": self.note,
                "rows": [{"name": r.name, "range": r.range, "cells": r.cells} for r in self.rows]}


NO_TRUTH: Final = ("the link-side figures (gear play, stick-slip, Hall position errors, "
                   "stiffness, DH lengths and joint offsets) are the prior's and cannot be "
                   "trusted beyond it; give a reference instrument with --tracker to identify "
                   "them, or measured tool positions with --reference or --touch-off for the "
                   "DH lengths, joint offsets and play")


def no_truth(obs: Observations) -> str:
    """What a calibration without a reference instrument leaves at the prior: all of the link
    side (:data:`NO_TRUTH`), or, with reference poses, all but what they fit."""
    if not obs.references:
        return NO_TRUTH
    return (f"the DH lengths, the joint offsets and the play of joints 1 to 3 are fitted from "
            f"{len(obs.references)} measured tool positions; the rest of the link side "
            "(stick-slip, Hall position errors, stiffness, joint 4's play and offset) is the "
            "prior's and cannot be trusted beyond it (a reference instrument, --tracker, "
            "identifies it)")


@dataclass(frozen=True, slots=True)
class CalibrationResult:
    """A finished (or partial) calibration: what was measured, what was fitted, the settings."""

    observations: Observations
    fitted: list[Fitted]
    settings: RobotSettings
    error: str | None = None
    sensitivity: Sensitivity | None = None
    #: How far the fitted arm's TCP is from the reference instrument's at each hold (mm).
    kinematic_mm: tuple[float, ...] = ()
    #: Per joint, what the held-out blocks kept of its speed model and why (JSON-ready:
    #: ``joint``, ``kept``, ``why``, every option's RMS per block, the blocks' floors).
    held_out: tuple[dict[str, Any], ...] = ()


#: Renders the calibration page of a result (HTML text).
PageRenderer = Callable[[CalibrationResult], str]


def run_sigma(run: SpeedRun) -> float:
    """A speed run's ratio error: its slope's standard error over its law (12) speed, and one
    pulse of rounding in its steps."""
    slope = (run.rate_sigma_rad_s or 0.0) / run.law_rad_s
    if not math.isfinite(slope):
        slope = 1.0
    return math.sqrt(slope ** 2 + (1.0 / max(run.steps, 1.0)) ** 2 + 1e-5 ** 2)


def session_scatter(obs: Observations) -> tuple[float, int]:
    """How much more the runs scatter than their own standard errors say, from the runs made
    twice (same joint, duty and direction): ``k = sqrt(mean z²)`` of their differences over
    their combined error, at least 1, and the number of pairs (1 without any)."""
    first: dict[tuple[int, int, int], SpeedRun] = {}
    z2: list[float] = []
    for run in obs.speeds:
        if run.samples == 0:  # a stall: no slope
            continue
        key = (run.joint, run.duty, run.direction)
        other = first.get(key)
        if other is None:
            first[key] = run
            continue
        z2.append((run.ratio - other.ratio) ** 2 / (run_sigma(run) ** 2
                                                    + run_sigma(other) ** 2))
    if not z2:
        return 1.0, 0
    return max(1.0, math.sqrt(math.fsum(z2) / len(z2))), len(z2)
