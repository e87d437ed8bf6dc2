"""The truth beside a reply: :class:`TruthProbe`, asked once per reply by the suites that judge
against a reference instrument (compiled in the release build: ``docs/performance.md``).

With ``ctx.truth`` set and an emulator behind the port, the truth of a reply is the emulator's
ground-truth sample of that very reply (``ArmEmulator.truth``: the true joints when the firmware
sampled them for it, matched by time and content), so like is compared with like and the
transmission lag (~2.2 ms at 115200 Bd) does not count as an error. Otherwise it is ``ctx.truth``
read when the reply is handled (a laser tracker on hardware; its latency is the instrument's).
Without ``ctx.truth`` there is no truth (the paper's situation).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Final

from armbench.bench.suites.base import SuiteContext
from armbench.drivers.model.kinematics import tcp_point
from armbench.drivers.transports.base import GroundTruth

if TYPE_CHECKING:
    from armbench.drivers.host.arm import JointState

__all__ = ["BELIEF_TOL_RAD", "TRUTH_SEARCH", "TruthProbe", "same_belief"]

#: How many of the emulator's newest truth samples are searched for a reply's own.
TRUTH_SEARCH: Final = 32
#: A truth sample is a reply's own when its firmware angles are the reply's within this (rad:
#: a wire tick).
BELIEF_TOL_RAD: Final = 2e-4


class TruthProbe:
    """The true joints / TCP beside a reply, when the bench has a reference instrument (see the
    module doc)."""

    def __init__(self, ctx: SuiteContext) -> None:
        # any arm-like object with an ``emulator`` (a compiled build checks no class here)
        self._arm: Any = ctx.arm
        self._source = ctx.truth
        self._settings = ctx.settings

    @property
    def available(self) -> bool:
        """Whether a reference instrument exists."""
        return self._source is not None

    def joints(self, state: JointState | None = None, *,
               motor: bool = False) -> tuple[float, ...] | None:
        """True joint angles (rad) beside ``state`` (or now), if the instrument gives them; with
        ``motor`` the motor shafts' angles where the emulator gives them (what the firmware's
        counters should say: the link's play and deflection are beyond any encoder's view)."""
        source = self._source
        if source is None:
            return None
        gt = self._matched(state)
        if gt is not None:
            side = gt.motor_rad if motor else None
            if side is None:
                side = gt.true_rad
            # the emulators' samples are tuples of floats already (once per reply)
            return side if type(side) is tuple else tuple(map(float, side))
        q = source.true_joints_rad()
        return None if q is None else tuple(float(v) for v in q)

    def position(self, state: JointState | None = None) -> tuple[float, float, float] | None:
        """True TCP position (m) beside ``state`` (or now)."""
        source = self._source
        if source is None:
            return None
        gt = self._matched(state)
        if gt is not None:  # the real arm's kinematics where the emulator has them
            actual = getattr(self._arm.emulator, "actual_settings", None)
            return tcp_point([float(v) for v in gt.true_rad],
                             actual if actual is not None else self._settings)
        p = source.true_position_m()
        return None if p is None else (float(p[0]), float(p[1]), float(p[2]))

    def _matched(self, state: JointState | None) -> GroundTruth | None:
        """The emulator's truth sample of ``state``'s reply: the newest one printed before the
        reply arrived whose firmware angles are the reply's (within a wire tick), among the
        newest :data:`TRUTH_SEARCH`; else None."""
        if state is None:
            return None
        emulator = self._arm.emulator  # the arm's current transport's (once per reply)
        if emulator is None:
            return None
        history: Sequence[GroundTruth] = emulator.truth
        n = len(history)
        t_max = state.t_s + 1e-9
        q = state.q_rad
        # the reply's own sample, as a rule, is the newest: tried first
        for k in range(1, min(TRUTH_SEARCH, n) + 1):
            gt = history[-k]
            if gt.t_s <= t_max and same_belief(gt.firmware_rad, q):
                return gt
        return None


def same_belief(fw: Sequence[float], q: Sequence[float]) -> bool:
    """Whether a truth sample's firmware angles ``fw`` are the reply's ``q`` within a wire tick
    (:data:`BELIEF_TOL_RAD`); the arm's four joints unrolled."""
    if len(fw) == len(q) == 4:
        return (abs(fw[0] - q[0]) <= BELIEF_TOL_RAD and abs(fw[1] - q[1]) <= BELIEF_TOL_RAD
                and abs(fw[2] - q[2]) <= BELIEF_TOL_RAD and abs(fw[3] - q[3]) <= BELIEF_TOL_RAD)
    return all(abs(float(a) - float(b)) <= BELIEF_TOL_RAD for a, b in zip(fw, q, strict=True))
