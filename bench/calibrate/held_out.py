"""Never worse, joint by joint, by construction: a fitted structure replaces the prior only where
it predicts the held-out blocks better beyond the noise.

The held-out blocks (``bench/calibrate/held_out_moves.py``) hold the motions the suites make (the
square's corners at full duty, its edges streamed) after the approaches and again at the end of
the session; nothing is fitted to them. Each candidate twin is replayed on each block, on
virtual time (:mod:`armbench.bench.calibrate.replay`), and compared with the arm's replies as
twin-check compares them (:mod:`armbench.bench.calibrate.divergence`): per block and joint, the
RMS divergence and the floor (what a perfect twin scores there from the capture's timing: the
noise). The candidates: the prior (the base settings' speed model), and each joint's speed models
the ladder's runs favour (:class:`~armbench.bench.calibrate.structure.SpeedOption`), every
joint's k-th candidate in the k-th twin (a joint's divergence is its own model's doing).

The noise of a comparison of two twins: the floor (squared), and the scatter of the difference
of their squared divergences, the moves being the independent units (the replies of one move
are not: a move's error is carried through it): the difference summed per command window, its
standard error :data:`SIGMAS` times. Per joint, a candidate is out when it is worse than the
prior on any block beyond the noise; of the others and the prior, the lowest mean square over
the blocks is taken, unless one with fewer parameters (the prior has none) is within the noise
of it: ties keep the simpler model or the prior. A candidate that explains one block (its RMS
within twin-check's allowance of the floor, or three quarters of the prior's mean square taken
away) and not another, that is better than the prior on one block and worse on another, each
beyond that block's floor (the blocks hold the same motions; one move is as good a reason to
doubt a law as to keep it), or that is ahead of the arm along the motion on one block and
behind it on another (each beyond that block's floor where the joint moves, the timing's share
of it, and :data:`SIGMAS` standard errors of the moves' scatter), says the arm's behaviour
moved during the session (its drives warming up): a constant fitted to the session predicts
neither, and the prior is kept. Then what the fit changes on every joint at once is judged the
same way, the speed models as chosen: the stop rule (a structure) kept only if some joint gets
better with it beyond the noise and the moves' scatter (a joint no twin predicts, one move
different by far either way, is no evidence) and none worse beyond the noise; the Hall
positions (measured against the motor-side truth) unless a joint gets worse. Without a held-out
block (a budget too small for one) every speed model keeps the prior, and says so.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from armbench.bench.calibrate.capture_data import CaptureData
from armbench.bench.calibrate.divergence import ArmSide, arm_side, diverge
from armbench.bench.calibrate.model import Fitted, HeldOut
from armbench.bench.calibrate.output import apply_fit
from armbench.bench.calibrate.replay import Counters, closer_counters, replay_twin
from armbench.bench.calibrate.stop_rule import STOP_RULE_KEY
from armbench.bench.calibrate.structure import SpeedOption, kept_speed, speed_keys
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.twin_parameters import TWIN
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.twin.physics import DEFAULT_ARM

__all__ = ["LEAD_S", "SIGMAS", "Block", "JointChoice", "Replayed", "blocks_of", "choose",
           "decide", "score", "shared_verdict", "worse"]

FloatArray = npt.NDArray[np.float64]

#: A block's replies start this long before its first command (s): the pose it starts from.
LEAD_S: Final = 0.1
#: A joint moves where the twin's speed exceeds this (rad/s: a few ticks a reply interval).
MOVING_RAD_S: Final = 0.05
#: The Hall positions' settings keys: every joint's reported angle depends on them.
_HALL_KEYS: Final = tuple(TWIN["hall_error_rad"].path(j) for j in range(4))


@dataclass(frozen=True, slots=True)
class Block:
    """A held-out block: its name, its stretch of the session's capture and what the capture
    alone says (the same against every twin)."""

    name: str
    data: CaptureData
    arm: ArmSide


def blocks_of(capture: CaptureData, windows: Sequence[HeldOut]) -> list[Block]:
    """The stretches of ``capture`` the held-out ``windows`` name (their commands and replies,
    the replies from :data:`LEAD_S` before the window), those with a command and a reply."""
    out = []
    for w in windows:
        commands = [c for c in capture.commands if w.start_s <= c[0] <= w.end_s]
        replies = [r for r in capture.replies if w.start_s - LEAD_S <= r[0] <= w.end_s]
        if commands and len(replies) > 2:
            data = CaptureData(capture.path, commands, replies, 0)
            out.append(Block(w.name, data, arm_side(data)))
    return out


@dataclass(frozen=True, slots=True)
class Replayed:
    """A twin on one held-out block: at each compared reply (its time, s) arm minus twin
    (``(n, 4)``, counts), the command in force (its index) and the way the twin's joint moves
    there (``(n, 4)``: ±1, 0 at rest), and per joint the floor (counts) over all the replies
    and over those where the joint moves (where the timing's share of it is)."""

    t_s: FloatArray
    diff_counts: FloatArray
    window: npt.NDArray[np.int64]
    floor: FloatArray
    way: FloatArray
    moving_floor: FloatArray

    @property
    def rms(self) -> FloatArray:
        """Per joint, the RMS divergence (counts)."""
        d = self.diff_counts
        return np.sqrt(np.mean(d * d, axis=0)) if len(d) else np.zeros(4)

    def lead(self, j: int) -> tuple[float, float]:
        """How far the twin's joint ``j`` is ahead of the arm's along its motion, on average
        where it moves (counts; negative: behind), and its standard error, the moves being the
        independent units (0 with one move: nothing to tell its scatter by)."""
        moving = self.way[:, j] != 0
        if not moving.any():
            return 0.0, 0.0
        x = -self.diff_counts[moving, j] * self.way[moving, j]
        lead = float(np.mean(x))
        per_move = np.bincount(self.window[moving], weights=x - lead)
        return lead, float(np.sqrt(np.sum(per_move ** 2)) / len(x))


#: A twin on every held-out block.
Scores = list[Replayed]


def _replay(data: CaptureData, settings: RobotSettings, hall_counters: Counters
            ) -> list[tuple[float, tuple[float, float, float, float]]]:
    from armbench.fakes.clock.vclock import run_virtual

    return run_virtual(replay_twin(data, settings, hall_counters=hall_counters))


def score(settings: RobotSettings, blocks: Sequence[Block], hall_counters: Counters) -> Scores:
    """Replay ``blocks`` into the twin of ``settings`` (its counters as its Hall sensors set
    them, or as a new arm's, per joint when a sequence) and compare; on its own virtual-time
    loop (call it where no loop runs: a worker thread)."""
    out = []
    for block in blocks:
        d = diverge(block.data, _replay(block.data, settings, hall_counters), settings,
                    block.arm)
        times = np.asarray(d.times)
        window = np.searchsorted(times, d.t_s, side="right").astype(np.int64)
        way = np.sign(d.speed_rad_s) * (np.abs(d.speed_rad_s) > MOVING_RAD_S)
        moving = np.asarray([d.floor_rad(rows=way[:, j] != 0)[j] for j in range(4)])
        out.append(Replayed(d.t_s, d.diff_rad * d.counts_per_rad, window,
                            d.floor_rad() * d.counts_per_rad, way, moving * d.counts_per_rad))
    return out


def _excess(a: Replayed, b: Replayed, j: int) -> tuple[float, float, float]:
    """How much more ``a``'s mean square divergence is than ``b``'s on joint ``j`` over the
    replies both compared (counts²), its standard error (the moves are the independent units:
    the squared differences summed per command window), and ``b``'s floor squared."""
    _, ia, ib = np.intersect1d(a.t_s, b.t_s, assume_unique=True, return_indices=True)
    if not len(ia):
        return 0.0, 0.0, float(b.floor[j] ** 2)
    x = a.diff_counts[ia, j] ** 2 - b.diff_counts[ib, j] ** 2
    per_move = np.bincount(a.window[ia], weights=x)
    n = len(x)
    return float(x.sum() / n), float(np.sqrt(np.sum(per_move ** 2)) / n), float(b.floor[j] ** 2)


#: How many standard errors of the moves' scatter a difference must exceed (beside the floor).
SIGMAS: Final = 2.0


def worse(a: Scores, b: Scores, j: int) -> bool:
    """Whether ``a`` diverges more than ``b`` on joint ``j`` on some block beyond the noise:
    by more than that block's floor (squared) and :data:`SIGMAS` standard errors of the moves'
    scatter (a twin whose residual error is large moves it by more than the timing does from
    one small change to the next: a move or two does not make it worse)."""
    for x, y in zip(a, b, strict=True):
        excess, se, floor2 = _excess(x, y, j)
        if excess > floor2 + SIGMAS * se:
            return True
    return False


def _better(a: Scores, b: Scores, j: int, sigmas: float = 0.0) -> bool:
    """Whether ``a`` diverges less than ``b`` on joint ``j`` over all blocks beyond the noise:
    its mean square by more than the blocks' floors squared (the timing a perfect twin meets:
    one move that ``b`` gets wrong by far is reason enough) and ``sigmas`` standard errors of
    the moves' scatter (what a change to every joint at once must show: on a joint neither
    twin predicts, a step loss the prior lacks, one move may differ by far either way)."""
    parts = [_excess(y, x, j) for x, y in zip(a, b, strict=True)]
    excess = sum(p[0] for p in parts)
    se = float(np.sqrt(sum(p[1] ** 2 for p in parts)))
    return excess > sum(p[2] for p in parts) + sigmas * se


@dataclass(frozen=True, slots=True)
class JointChoice:
    """What the held-out blocks chose for a joint's speed model: the option's name (``prior``
    or a :class:`SpeedOption`'s), why, and every option's RMS (counts) per block with the
    blocks' floors."""

    joint: int
    kept: str
    why: str
    rms: dict[str, list[float]]
    floor: list[float]

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready mapping."""
        return {"joint": self.joint, "kept": self.kept, "why": self.why, "rms_counts": self.rms,
                "floor_counts": self.floor}


#: A twin explains a block where its RMS is within twin-check's allowance of the block's floor
#: (3 × floor + 2 counts) or it takes away this much of the prior's mean square.
EXPLAINS: Final = 0.75


def _moved(score: Scores, prior: Scores, j: int, blocks: Sequence[str]) -> str | None:
    """Whether the arm's joint ``j`` behaved otherwise on one block than on another, as a twin
    fitted to the session shows it: it explains one block and not another (:data:`EXPLAINS`),
    or it is better than the prior on one block and worse on another, each beyond that block's
    floor (the blocks hold the same motions: a constant that wins on one and loses on the other
    fits a moment of the session, not the arm of the suites' runs that follow; a win one move
    carries counts, as it does for the choice),
    or it is ahead of the arm along the motion on one and behind on another, each by more than
    that block's floor where the joint moves and :data:`SIGMAS` standard errors of the moves'
    scatter (a twin off by a constant share is off the same way on both; a perfect one is off
    either way by the timing there, which one move of a loaded host's may carry far). What it
    shows, or None."""
    explained = [r.rms[j] <= 3.0 * r.floor[j] + 2.0 or r.rms[j] ** 2 <= (1 - EXPLAINS) * p.rms[j]
                 ** 2 for r, p in zip(score, prior, strict=True)]
    if any(explained) and not all(explained):
        a, b = explained.index(True), explained.index(False)
        return (f"explains the {blocks[a]} block (RMS {score[a].rms[j]:.3g} counts against the "
                f"prior's {prior[a].rms[j]:.3g}) and not the {blocks[b]} block "
                f"({score[b].rms[j]:.3g} against {prior[b].rms[j]:.3g})")
    gains = [_excess(p, r, j) for r, p in zip(score, prior, strict=True)]
    better = [gain > floor2 for gain, _, floor2 in gains]
    lost = [-gain > floor2 for gain, _, floor2 in gains]
    if any(better) and any(lost):
        a, b = better.index(True), lost.index(True)
        return (f"is better than the prior on the {blocks[a]} block beyond its floor (RMS "
                f"{score[a].rms[j]:.3g} counts against {prior[a].rms[j]:.3g}) and worse on the "
                f"{blocks[b]} block beyond its floor ({score[b].rms[j]:.3g} against "
                f"{prior[b].rms[j]:.3g})")
    ahead: list[float] = []
    behind: list[float] = []
    for r in score:
        lead, se = r.lead(j)
        noise = float(r.moving_floor[j]) + SIGMAS * se
        if lead > noise:
            ahead.append(lead)
        elif lead < -noise:
            behind.append(lead)
    if not ahead or not behind:
        return None
    return ("is ahead of the arm along the motion on a block by "
            f"{max(ahead):.3g} counts and behind on another by {-min(behind):.3g}")


def decide(j: int, names: Sequence[str], sizes: Sequence[int], scores: Sequence[Scores],
           blocks: Sequence[str]) -> JointChoice:
    """Joint ``j``'s (0-based) choice among the options ``names`` (the prior first, then each
    candidate; ``sizes``: their numbers of parameters) by their ``scores`` on the held-out
    blocks named ``blocks`` (see the module doc)."""
    prior = scores[0]
    total = [float(sum(np.mean(r.diff_counts[:, j] ** 2) for r in s if len(r.t_s)))
             for s in scores]
    fair = [k for k in range(len(scores)) if k == 0 or not worse(scores[k], prior, j)]
    best = min(fair, key=lambda k: total[k])
    tied = [k for k in fair if k == best or not _better(scores[best], scores[k], j)]
    chosen = min(tied, key=lambda k: (k != 0, sizes[k], total[k]))
    where = " / ".join(blocks)
    table = ", ".join(f"{names[k]} {' / '.join(f'{r.rms[j]:.3g}' for r in scores[k])}"
                      for k in range(len(scores)))
    floors = " / ".join(f"{r.floor[j]:.3g}" for r in prior)
    shown = (f"held out ({where}: {sum(len(r.t_s) for r in prior)} replies): RMS counts "
             f"{table}; floor {floors}")
    moved = _moved(scores[chosen], prior, j, blocks) if chosen else None
    if moved is not None:
        why = (f"the prior kept: the arm's behaviour moved during the session ({names[chosen]} "
               f"{moved}: a constant fitted to the session predicts neither); {shown}")
        chosen = 0
    elif chosen == 0:
        why = ("the prior kept: no candidate predicts the held-out blocks better beyond the "
               f"noise; {shown}") if len(scores) > 1 else f"the prior kept; {shown}"
    else:
        why = (f"{names[chosen]} kept: better than the prior beyond the noise and worse on no "
               f"block; {shown}")
    return JointChoice(j + 1, names[chosen], why,
                       {names[k]: [float(r.rms[j]) for r in scores[k]]
                        for k in range(len(scores))},
                       [float(r.floor[j]) for r in prior])


def _with_speed(fitted: Sequence[Fitted], j: int, speed: Sequence[Fitted]) -> list[Fitted]:
    """``fitted`` with joint ``j``'s speed model replaced by ``speed``."""
    keys = speed_keys(j)
    return [*(f for f in fitted if f.key not in keys), *speed]


def _prior_speed(j: int, base: RobotSettings, reason: str) -> list[Fitted]:
    physics = emulator_settings(base).physics or DEFAULT_ARM
    return kept_speed(j, base.joints[j].gear_ratio, physics.joints[j], reason)


def choose(fitted: Sequence[Fitted], base: RobotSettings,
           options: Mapping[int, Sequence[SpeedOption]], blocks: Sequence[Block],
           hall_counters: Counters | None = None) -> tuple[list[Fitted], list[JointChoice]]:
    """``fitted`` with each joint's speed model and the shared values (stop rule, Hall
    positions) as the held-out ``blocks`` choose them (see the module doc), and the choice of
    each joint with its reasons. ``hall_counters``: whether the arm's counters were as its Hall
    sensors set them when the blocks began (a session whose approaches crossed them all); None:
    as the base twin's replay says, joint by joint (:func:`closer_counters`)."""
    out = list(fitted)
    if not blocks:
        for j in range(4):
            out = _with_speed(out, j, _prior_speed(
                j, base, "no held-out block of the suites' motions (the budget holds none): "
                         "the prior kept"))
        return out, []
    hall = hall_counters
    if hall is None:
        default = {h: score(base, blocks, h) for h in (False, True)}
        hall = closer_counters(*(np.sum([r.rms ** 2 for r in default[h]], axis=0).tolist()
                                 for h in (False, True)))
    with_prior = list(out)
    for j in range(4):
        with_prior = _with_speed(with_prior, j, _prior_speed(j, base, ""))
    width = max((len(options.get(j, ())) for j in range(4)), default=0)
    scores = [score(apply_fit(base, with_prior), blocks, hall)]
    for k in range(width):
        twin = list(with_prior)
        for j in range(4):
            if k < len(options.get(j, ())):
                twin = _with_speed(twin, j, options[j][k].fitted)
        scores.append(score(apply_fit(base, twin), blocks, hall))
    choices = []
    for j in range(4):
        mine = list(options.get(j, ()))
        names = ["prior", *(o.name for o in mine)]
        choice = decide(j, names, [0, *(o.n_params for o in mine)], scores[:len(names)],
                        [b.name for b in blocks])
        choices.append(choice)
        picked = next((o for o in mine if o.name == choice.kept), None)
        out = _with_speed(out, j, _prior_speed(j, base, choice.why) if picked is None else [
            replace(f, reason=f"{f.reason}; {choice.why}")
            if f.key == TWIN["loss_law"].path(j) else f for f in picked.fitted])
    return _judge_shared(out, base, blocks, hall), choices


def _judge_shared(fitted: list[Fitted], base: RobotSettings, blocks: Sequence[Block],
                  hall: Counters) -> list[Fitted]:
    """``fitted`` with the values every joint's reported angle depends on judged on the
    held-out ``blocks``, the speed models as chosen: the stop rule (a structure) kept only where
    the twin with it diverges less than without it on some joint (beyond the noise and the
    moves' scatter) and more on none, beyond the noise (a tie keeps the prior); then the Hall
    positions (measured against the motor-side truth, each with its interval) kept unless the
    twin with them diverges more on a joint."""
    judged = _judge(fitted, base, blocks, hall, (STOP_RULE_KEY,), need_better=True)
    return _judge(judged, base, blocks, hall, _HALL_KEYS, need_better=False)


def shared_verdict(mine: Scores, other: Scores, need_better: bool) -> tuple[list[int], bool]:
    """The joints (1-based) on which the twin with a shared value (``mine``) diverges more than
    without it (``other``) beyond the noise, and whether it is better enough to keep: always
    unless ``need_better``, else on some joint beyond the noise and the moves' scatter."""
    lost = [j + 1 for j in range(4) if worse(mine, other, j)]
    return lost, not need_better or any(_better(mine, other, j, SIGMAS) for j in range(4))


def _judge(fitted: list[Fitted], base: RobotSettings, blocks: Sequence[Block], hall: Counters,
           keys: Sequence[str], need_better: bool) -> list[Fitted]:
    """``fitted`` with its identified values of ``keys`` put back to the prior where the twin
    with them diverges more than without them on a joint beyond the noise, or (``need_better``)
    less on none beyond the noise and the moves' scatter."""
    shared = [f for f in fitted if f.key in keys and f.identified]
    if not shared:
        return fitted
    without = [f for f in fitted if f not in shared]
    lost, better = shared_verdict(score(apply_fit(base, fitted), blocks, hall),
                                  score(apply_fit(base, without), blocks, hall), need_better)
    if not lost and better:
        return fitted
    why = ("held out: the twin with it diverges more than without it on joint "
           f"{', '.join(map(str, lost))} beyond the noise: the prior kept" if lost else
           "held out: the twin with it predicts no joint better than without it beyond the "
           "noise: the prior kept")
    return [replace(f, identified=False, reason=f"{why} (fitted: {f.reason})")
            if f in shared else f for f in fitted]
