"""What every suite and its report section agree on, and where each suite's contract is found.

A suite's contract names what the suite records and the report reads: the suite's name, its
metric names, its trial and suite parameters, the keys of its samples and events, and the
headline figures the report leads with. Each contract is defined with its suite, in a light
module of plain data (no numpy, no driver) that the suite and its report section both import and
that calls :func:`register` when imported. This module holds what every contract shares
(:class:`Headline`, :class:`SampleKeys`, the samples' rounding) and the registry: record readers
(the record, the metrics, the report) find a contract by its suite's name with :func:`contract`,
never by importing a suite.

The registry is filled on first use by discovery, so adding a suite edits no list: every module
of :data:`BUILTIN_PACKAGE` whose name ends in :data:`CONTRACT_SUFFIX`, then every entry point of
the group :data:`ENTRY_POINT_GROUP` (another distribution's suites). Only those modules are
imported, never the suites themselves.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import pkgutil
import warnings
from dataclasses import dataclass
from typing import Final, Protocol, TypeVar, overload, runtime_checkable

__all__ = [
    "ACCURACY",
    "BUILTIN_PACKAGE",
    "CONTRACT_SUFFIX",
    "ENTRY_POINT_GROUP",
    "JOINTS",
    "POS_DECIMALS",
    "RAD_DECIMALS",
    "REPEATABILITY",
    "SAMPLE",
    "STARTUP",
    "TWIN_CHECK",
    "AccuracyNames",
    "Headline",
    "RepeatabilityNames",
    "SampleKeys",
    "StartupNames",
    "SuiteContract",
    "TwinCheckNames",
    "UnknownContractError",
    "contract",
    "contracts",
    "forget",
    "register",
    "resolution",
]

#: Decimal places of positions in samples (m): 0.1 µm, far below any error the bench reports.
POS_DECIMALS: Final = 7
#: Decimal places of joint angles in samples (rad): 1 µrad (the wire resolution is 100 µrad).
RAD_DECIMALS: Final = 6

#: The smallest step a figure in this unit can resolve, given the samples' rounding: a figure
#: (a spread, a bias) below it is zero as far as the measurement can tell.
_RESOLUTION: Final[dict[str, float]] = {
    "m": 10.0 ** -POS_DECIMALS,
    "mm": 10.0 ** -(POS_DECIMALS - 3),
    "rad": 10.0 ** -RAD_DECIMALS,
    "mrad": 10.0 ** -(RAD_DECIMALS - 3),
    "s": 1e-6,
}


def resolution(unit: str) -> float | None:
    """The resolution of a figure in ``unit`` (None for a unit with no known resolution)."""
    return _RESOLUTION.get(unit)


@dataclass(frozen=True, slots=True)
class Headline:
    """A headline figure of a suite: the metric's name (or, with ``worst_of``, the ``fnmatch``
    pattern of the metrics whose worst value is shown), a label for people, whether higher is
    worse, and the key of the paper's reference figure in the record's ``reference`` table where
    the paper has one."""

    label: str
    metric: str
    worst_of: bool = False
    higher_is_worse: bool = True
    paper: str | None = None


@dataclass(frozen=True, slots=True)
class SampleKeys:
    """Keys of the samples every suite records (see ``bench/suites/_common.py``)."""

    t: str = "t_s"
    q: str = "q_rad"
    reported: str = "reported_m"
    true: str = "true_m"
    commanded: str = "commanded_m"
    kind: str = "kind"
    pose: str = "pose"
    direction: str = "direction"
    event: str = "event"


SAMPLE: Final = SampleKeys()


@runtime_checkable
class SuiteContract(Protocol):
    """What every suite's contract says: the suite's name, its place in the default run and in
    the report (``order``: lower first), whether it records true figures beside the encoders',
    the suite class that runs it (``"module:Class"``, by name: this layer imports no suite;
    ``None``: recorded by something else) and the headline figures the report leads with."""

    @property
    def suite(self) -> str: ...

    @property
    def order(self) -> int: ...

    @property
    def has_true_figures(self) -> bool: ...

    @property
    def implementation(self) -> str | None: ...

    @property
    def headlines(self) -> tuple[Headline, ...]: ...


#: The package whose modules named ``*<CONTRACT_SUFFIX>`` are the built-in suites' contracts.
BUILTIN_PACKAGE: Final = "armbench.bench.suites"
#: How a built-in contract module's name ends (``accuracy_contract``): only these are imported.
CONTRACT_SUFFIX: Final = "_contract"
#: Entry-point group under which other distributions register a suite's contract, as
#: ``name = "package.module:CONTRACT"`` (the module is imported, the object registered).
ENTRY_POINT_GROUP: Final = "armbench.suite_contracts"

_CONTRACTS: dict[str, SuiteContract] = {}
_discovery = {"done": False}
_C = TypeVar("_C")


class UnknownContractError(LookupError):
    """No registered contract for a suite name (or not one of the shape the reader needs)."""


def register(contract: _C) -> _C:
    """Add a suite's contract to the registry (called by the module that defines it: no list to
    edit elsewhere); a second contract of the same suite name is a bug."""
    if not isinstance(contract, SuiteContract):
        raise TypeError(f"{contract!r} is not a suite contract (suite, order, has_true_figures, "
                        "implementation, headlines)")
    if contract.suite in _CONTRACTS:
        raise ValueError(f"two contracts of suite {contract.suite!r}")
    _CONTRACTS[contract.suite] = contract
    return contract


def _discover() -> None:
    """Import every contract module once: the built-ins, then the entry points. A contract that
    cannot be loaded is left out with a warning (its suite is then shown as any unknown suite),
    so one broken plug-in does not stop a record from being read."""
    if _discovery["done"]:
        return
    _discovery["done"] = True
    package = importlib.import_module(BUILTIN_PACKAGE)
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda i: i.name):
        if info.name.endswith(CONTRACT_SUFFIX):
            importlib.import_module(f"{BUILTIN_PACKAGE}.{info.name}")
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            found = ep.load()
            if not any(c is found for c in _CONTRACTS.values()):
                register(found)
        except Exception as exc:  # a plug-in's failure: reported, not fatal
            warnings.warn(f"suite contract entry point {ep.name} = {ep.value}: {exc}",
                          RuntimeWarning, stacklevel=2)


def forget(suite: str) -> None:
    """Remove a suite's contract and discover again on next use (a test's suite, unregistered)."""
    _CONTRACTS.pop(suite, None)
    _discovery["done"] = False


def contracts() -> tuple[SuiteContract, ...]:
    """Every suite's contract, by ``order`` (then by name): the default run's and the report's
    order of suites."""
    _discover()
    return tuple(sorted(_CONTRACTS.values(), key=lambda c: (c.order, c.suite)))


@overload
def contract(suite: str) -> SuiteContract: ...
@overload
def contract(suite: str, shape: type[_C]) -> _C: ...
def contract(suite: str, shape: type[object] = SuiteContract) -> object:
    """The registered contract of ``suite``. ``shape`` (a ``runtime_checkable`` protocol of the
    names a reader uses) is checked, so a reader fails with the suite's name rather than on a
    missing attribute; :class:`UnknownContractError` when there is none or it lacks a name."""
    _discover()
    found = _CONTRACTS.get(suite)
    if found is None:
        raise UnknownContractError(f"no contract of suite {suite!r} (known: "
                                   f"{', '.join(c.suite for c in contracts())})")
    if not isinstance(found, shape):
        raise UnknownContractError(f"the contract of suite {suite!r} lacks names "
                                   f"{shape.__name__} needs")
    return found


@dataclass(frozen=True, slots=True)
class AccuracyNames:
    """The accuracy suite (the paper's square, §7)."""

    suite: str = "accuracy"
    #: place in the default run and in the report (lower first)
    order: int = 10
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = True
    #: what runs the suite: ``module:Class``, imported only when the suite is loaded
    implementation: str | None = "armbench.bench.suites.accuracy:AccuracySuite"
    styles: tuple[str, ...] = ("paper", "coordinated")
    paper: str = "paper"
    coordinated: str = "coordinated"
    # trial parameters
    style: str = "style"
    lap: str = "lap"
    # suite parameters; ``paper_mean`` is also the key of the paper's figure in a record's
    # ``reference`` table
    centre: str = "centre_m"
    side: str = "side_m"
    paper_mean: str = "paper_mean_error_mm"
    # figures of a style (suffixes of its metric names)
    mean: str = "mean_mm"
    rms: str = "rms_mm"
    max: str = "max_mm"
    true_mean: str = "true_mean_mm"
    belief_mean: str = "belief_mean_mm"
    belief_max: str = "belief_max_mm"
    lap_time: str = "lap_time_s"
    laps: str = "laps"

    def metric(self, style: str, figure: str) -> str:
        """``accuracy.<style>.<figure>``."""
        return f"{self.suite}.{style}.{figure}"

    @property
    def improvement(self) -> str:
        """Paper-style mean over coordinated mean."""
        return f"{self.suite}.improvement_ratio"

    @property
    def true_improvement(self) -> str:
        return f"{self.suite}.true_improvement_ratio"

    @property
    def headlines(self) -> tuple[Headline, ...]:
        return (
            Headline("paper-style mean path error", self.metric(self.paper, self.mean),
                     paper=self.paper_mean),
            Headline("coordinated mean path error", self.metric(self.coordinated, self.mean)),
            Headline("coordinated max path error", self.metric(self.coordinated, self.max)),
            Headline("improvement (paper-style / coordinated)", self.improvement,
                     higher_is_worse=False),
            Headline("worst firmware belief vs truth", f"{self.suite}.*.{self.belief_max}",
                     worst_of=True),
        )


@dataclass(frozen=True, slots=True)
class RepeatabilityNames:
    """The repeatability suite (ISO 9283)."""

    suite: str = "repeatability"
    #: place in the default run and in the report (lower first)
    order: int = 20
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = True
    #: what runs the suite: ``module:Class``, imported only when the suite is loaded
    implementation: str | None = "armbench.bench.suites.repeatability:RepeatabilitySuite"
    # trial parameters and their kinds
    kind: str = "kind"
    speed: str = "speed_pct"
    duty: str = "duty"
    cycle: str = "cycle"
    pose_kind: str = "pose"
    vap_kind: str = "vap"
    path_kind: str = "path"
    # suite parameters
    cube_centre: str = "cube_centre_m"
    cube_side: str = "cube_side_m"
    plane: str = "plane"
    speeds: str = "speeds_pct"
    # figures
    ap: str = "ap_mm"
    rp: str = "rp_mm"
    vap: str = "vap_mm"
    at: str = "at_mm"
    rt: str = "rt_mm"
    rd: str = "rd_mm"
    cycles: str = "cycles"

    def speed_label(self, speed_pct: float) -> str:
        """The name part of a speed: ``v100``, ``v50``, ``v10`` (``v12.5`` for fractions)."""
        return f"v{speed_pct:g}"

    def at_speed(self, speed_pct: float) -> str:
        """``repeatability.v100``: the prefix of every figure at that speed."""
        return f"{self.suite}.{self.speed_label(speed_pct)}"

    def pose_metric(self, speed_pct: float, pose: str, figure: str) -> str:
        """``repeatability.v100.p1.rp_mm``."""
        return f"{self.at_speed(speed_pct)}.{pose.lower()}.{figure}"

    def path_prefix(self, speed_pct: float) -> str:
        return f"{self.at_speed(speed_pct)}.path"

    @property
    def cycle_prefix(self) -> str:
        """Per-trial figures of one cycle: ``repeatability.cycle``."""
        return f"{self.suite}.cycle"

    @property
    def trial_path_prefix(self) -> str:
        """Per-trial figures of one path: ``repeatability.path``."""
        return f"{self.suite}.path"

    @property
    def headlines(self) -> tuple[Headline, ...]:
        s = self.suite
        return (
            Headline("worst pose accuracy AP", f"{s}.v*.p?.{self.ap}", worst_of=True),
            Headline("worst pose repeatability RP", f"{s}.v*.p?.{self.rp}", worst_of=True),
            Headline("worst multi-directional vAP", f"{s}.v*.p?.{self.vap}", worst_of=True),
            Headline("worst path accuracy AT", f"{s}.v*.path.{self.at}", worst_of=True),
        )


@dataclass(frozen=True, slots=True)
class StartupNames:
    """The startup-recovery suite (paper §5.2): power cuts and EEPROM wear."""

    suite: str = "startup-recovery"
    #: place in the default run and in the report (lower first)
    order: int = 30
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = False
    #: what runs the suite: ``module:Class``, imported only when the suite is loaded
    implementation: str | None = "armbench.bench.suites.startup_recovery:StartupRecoverySuite"
    prefix: str = "startup"
    # trial parameters and their kinds
    kind: str = "kind"
    cut_kind: str = "cut"
    wear_kind: str = "wear"
    condition: str = "condition"
    joints: str = "joints"
    cut: str = "cut"
    duration: str = "duration_s"
    # events (samples with an ``event`` key) and their fields
    ev_fault: str = "fault"
    ev_power_restore: str = "power_restore"
    ev_ready: str = "ready"
    ev_recovered: str = "recovered"
    ev_timeout: str = "timeout"
    ev_outcome: str = "outcome"
    ev_position_check: str = "position_check"
    ev_wear_phase: str = "wear_phase"
    ev_wear: str = "wear"
    ev_rescue: str = "rescue"
    ev_skipped: str = "skipped"
    f_recovered: str = "recovered"
    f_failure: str = "failure"
    f_recovery: str = "recovery_s"
    f_expected: str = "expected_to_recover"
    f_error_mrad: str = "error_mrad"
    f_error_mm: str = "error_mm"

    def metric(self, figure: str) -> str:
        """``startup.<figure>`` (the metrics keep the short prefix of the limits files)."""
        return f"{self.prefix}.{figure}"

    def condition_rate(self, condition: str) -> str:
        """``startup.<condition>.success_rate_pct``."""
        return f"{self.prefix}.{condition}.success_rate_pct"

    def phase_writes(self, phase: str) -> str:
        """``startup.<phase>.eeprom_writes_per_hour``."""
        return f"{self.prefix}.{phase}.eeprom_writes_per_hour"

    # per trial
    @property
    def recovered(self) -> str:
        return self.metric("recovered")

    @property
    def recovery_time(self) -> str:
        return self.metric("recovery_time_s")

    @property
    def first_reply(self) -> str:
        return self.metric("first_reply_s")

    @property
    def position_error_mrad(self) -> str:
        return self.metric("position_error_mrad")

    @property
    def position_error_mm(self) -> str:
        return self.metric("position_error_mm")

    @property
    def eeprom_writes(self) -> str:
        return self.metric("eeprom_writes")

    # per suite
    @property
    def trials_measured(self) -> str:
        return self.metric("trials_measured")

    @property
    def success_rate(self) -> str:
        return self.metric("success_rate_pct")

    @property
    def expected_success_rate(self) -> str:
        return self.metric("expected_success_rate_pct")

    @property
    def recovery_time_max(self) -> str:
        return self.metric("recovery_time_max_s")

    @property
    def recovery_time_mean(self) -> str:
        return self.metric("recovery_time_mean_s")

    @property
    def position_error_max(self) -> str:
        return self.metric("position_error_max_mrad")

    @property
    def recovered_position_error_max(self) -> str:
        return self.metric("recovered_position_error_max_mrad")

    @property
    def eeprom_writes_per_cut(self) -> str:
        return self.metric("eeprom_writes_per_cut")

    @property
    def eeprom_writes_per_hour(self) -> str:
        return self.metric("eeprom_writes_per_hour")

    @property
    def eeprom_cell_wear_per_hour(self) -> str:
        return self.metric("eeprom_cell_wear_per_hour")

    @property
    def eeprom_life_years(self) -> str:
        return self.metric("eeprom_life_years")

    @property
    def eeprom_life_hours(self) -> str:
        return self.metric("eeprom_life_hours")

    @property
    def headlines(self) -> tuple[Headline, ...]:
        return (
            Headline("recovered after a power cut", self.success_rate, higher_is_worse=False),
            Headline("recovered where §5.2 can", self.expected_success_rate,
                     higher_is_worse=False),
            Headline("slowest recovery", self.recovery_time_max),
            Headline("worst error after a recovery", self.recovered_position_error_max),
            Headline("EEPROM life at the configured use", self.eeprom_life_years,
                     higher_is_worse=False),
        )


ACCURACY: Final = register(AccuracyNames())
REPEATABILITY: Final = register(RepeatabilityNames())
STARTUP: Final = register(StartupNames())


@dataclass(frozen=True, slots=True)
class JointsNames:
    """The joints suite (ISO 230-2 bidirectional positioning of each joint)."""

    suite: str = "joints"
    #: place in the default run and in the report (lower first)
    order: int = 40
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = True
    #: what runs the suite: ``module:Class``, imported only when the suite is loaded
    implementation: str | None = "armbench.bench.suites.joints:JointsSuite"
    prefix: str = "joints"
    # trial parameter and the sample key of the true angle
    joint: str = "joint"
    true_angle: str = "true_rad"
    # figures per joint (mrad), of the reported angle, and with ``true_`` of the true one
    accuracy: str = "accuracy_mrad"
    repeatability: str = "repeatability_mrad"
    reversal: str = "reversal_mrad"
    mean_reversal: str = "mean_reversal_mrad"
    systematic: str = "systematic_mrad"
    true: str = "true_"

    def metric(self, joint: int, figure: str, true: bool = False) -> str:
        """``joints.j<N>.[true_]<figure>``."""
        return f"{self.prefix}.j{joint}.{self.true if true else ''}{figure}"

    @property
    def figures(self) -> tuple[str, ...]:
        """The figures shown per joint, in order."""
        return (self.accuracy, self.repeatability, self.reversal, self.systematic)

    @property
    def headlines(self) -> tuple[Headline, ...]:
        p = self.prefix
        return (
            Headline("worst joint accuracy A", f"{p}.j*.{self.accuracy}", worst_of=True),
            Headline("worst joint repeatability R", f"{p}.j*.{self.repeatability}",
                     worst_of=True),
            Headline("worst joint reversal B", f"{p}.j*.{self.reversal}", worst_of=True),
            Headline("worst true joint accuracy A", f"{p}.j*.{self.true}{self.accuracy}",
                     worst_of=True),
        )


JOINTS: Final = register(JointsNames())


@dataclass(frozen=True, slots=True)
class TwinCheckNames:
    """``armbench twin-check --out``: how well the twin predicts an arm's capture (the record of
    :mod:`armbench.bench.twin_record`; the report's twin-check section)."""

    suite: str = "twin-check"
    #: place in the default run and in the report (lower first)
    order: int = 90
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = False
    #: what runs the suite as ``module:Class`` (None: recorded by ``armbench twin-check``)
    implementation: str | None = None
    prefix: str = "twin"
    # suite parameters: the inputs and how the series were kept
    capture: str = "capture"
    capture_sha256: str = "capture_sha256"
    settings: str = "settings"
    settings_sha256: str = "settings_sha256"
    config: str = "config"
    config_sha256: str = "config_sha256"
    buckets: str = "series_buckets"
    # samples: ``kind`` (SAMPLE.kind) is one of these
    series_kind: str = "series"
    arrival_kind: str = "arrival"
    # keys of a series sample (one joint at one reply of the capture)
    joint: str = "joint"
    arm: str = "arm_rad"
    twin: str = "twin_rad"
    divergence: str = "divergence_counts"
    # keys of an arrival sample (one command both streams arrived at; SAMPLE.t is its time)
    arm_arrival: str = "arm_s"
    twin_arrival: str = "twin_s"
    arrival_dt: str = "dt_s"
    # figures per joint (twin.j<N>.<figure>)
    rms_counts: str = "rms_counts"
    max_counts: str = "max_counts"
    rms_rad: str = "rms_rad"
    max_rad: str = "max_rad"
    # figures of the whole check (twin.<figure>)
    mean_dt: str = "arrival.mean_dt_s"
    max_abs_dt: str = "arrival.max_abs_dt_s"
    moves: str = "arrival.moves"
    compared: str = "arrival.compared"
    arm_only: str = "arrival.arm_only"
    twin_only: str = "arrival.twin_only"
    replies: str = "replies_compared"
    untimed: str = "replies_untimed"
    sessions: str = "sessions"
    # the floor and the verdict relative to it (twin.j<N>.<figure>, twin.<figure>)
    floor_counts: str = "floor_counts"
    allowed_counts: str = "allowed_counts"
    per_allowed: str = "rms_per_allowed"
    settled_counts: str = "settled_counts"
    settled_per_allowed: str = "settled_per_allowed"
    rms_dt: str = "arrival.rms_dt_s"
    floor_dt: str = "arrival.floor_s"
    arrival_per_allowed: str = "arrival.rms_per_allowed"
    scatter: str = "timing_scatter_s"
    reaction: str = "reaction_scatter_s"
    shift_mean: str = "start_shift.mean_s"
    shift_max: str = "start_shift.max_abs_s"
    tcp_floor: str = "tcp.floor_mm"
    tcp_per_allowed: str = "tcp.rms_per_allowed"
    tcp_samples: str = "tcp.samples"
    tcp_rest: str = "tcp.rest_rms_mm"
    tcp_rest_per_allowed: str = "tcp.rest_rms_per_allowed"
    tcp_rms: str = "tcp.rms_mm"
    tcp_max: str = "tcp.max_mm"

    def joint_metric(self, joint: int, figure: str) -> str:
        """``twin.j<N>.<figure>``."""
        return f"{self.prefix}.j{joint}.{figure}"

    def metric(self, figure: str) -> str:
        """``twin.<figure>``."""
        return f"{self.prefix}.{figure}"

    @property
    def headlines(self) -> tuple[Headline, ...]:
        p = self.prefix
        return (
            Headline("worst joint RMS divergence", f"{p}.j*.{self.rms_counts}", worst_of=True),
            Headline("worst joint RMS over its allowance", f"{p}.j*.{self.per_allowed}",
                     worst_of=True),
            Headline("worst joint largest divergence", f"{p}.j*.{self.max_counts}",
                     worst_of=True),
            Headline("largest arrival-time difference", self.metric(self.max_abs_dt)),
            Headline("TCP RMS divergence", self.metric(self.tcp_rms)),
        )


TWIN_CHECK: Final = register(TwinCheckNames())
