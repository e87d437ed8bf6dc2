"""Never worse, joint by joint, by construction (``bench/calibrate/held_out.py``): a fitted speed
model replaces the prior only where it predicts the held-out blocks better beyond the noise and
no block worse, ties keep the simpler model or the prior; and the held-out blocks of the
procedure (``bench/calibrate/held_out_moves.py``) hold the suites' motions, within the budget.

The choice is tested on divergences made here (one joint, two blocks, a known floor): the
effects are known exactly only so. The procedure runs on the emulator (virtual time)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from armbench.bench.calibrate import calibrate_port
from armbench.bench.calibrate.held_out import Replayed, decide, shared_verdict
from armbench.bench.calibrate.held_out_moves import BLOCK_SHARE
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.reports.pages.calibration_page import render_page

FloatArray = npt.NDArray[np.float64]
REPLY_S = 0.005
MOVES = 20
BLOCK_S = 10.0


def _block(rms_counts: float, seed: int, floor: float = 2.0, lead: float = 0.0,
           moving_floor: float | None = None) -> Replayed:
    """A block of 10 s, 20 moves, where joint 2 diverges by about ``rms_counts`` RMS (noise of
    that size, drawn per reply; the twin ``lead`` counts ahead of the arm along the motion on
    top) and its floor is ``floor`` (``moving_floor`` where it moves; the same by default); the
    joint moves each way in turn."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, BLOCK_S, REPLY_S)
    window = (t // (BLOCK_S / MOVES)).astype(np.int64)
    way = np.zeros((len(t), 4))
    way[:, 1] = np.where(window % 2 == 0, 1.0, -1.0)
    diff = np.zeros((len(t), 4))
    diff[:, 1] = rng.normal(0.0, rms_counts, len(t)) - lead * way[:, 1]
    return Replayed(t, diff, window, np.full(4, floor), way,
                    np.full(4, floor if moving_floor is None else moving_floor))


NAMES = ["prior", "duty", "torque+scale"]
SIZES = [0, 3, 2]


def _choose(prior: tuple[float, float], duty: tuple[float, float],
            torque: tuple[float, float]) -> str:
    scores = [[_block(a, 1), _block(b, 2)] for a, b in (prior, duty, torque)]
    return decide(1, NAMES, SIZES, scores, ["suite", "end"]).kept


def test_better_beyond_the_noise_replaces_the_prior() -> None:
    """The prior diverges by 50 counts on both blocks, the duty law by 3 and torque+scale by 60
    (the issue's threshold arm, joint 2): the duty law is kept, and the reason gives every
    option's RMS per block and the floor."""
    choice = decide(1, NAMES, SIZES, [[_block(a, 1), _block(b, 2)] for a, b in
                                      ((50, 49), (3, 3), (60, 62))], ["suite", "end"])
    assert choice.kept == "duty"
    assert "duty kept: better than the prior beyond the noise" in choice.why
    assert "suite / end" in choice.why and "floor 2 / 2" in choice.why
    assert choice.rms["prior"][0] > 45 and choice.rms["duty"][1] < 4


def test_within_the_noise_the_prior_is_kept() -> None:
    """Candidates within the floor of the prior (2 counts): a tie keeps the prior."""
    assert _choose((2.2, 2.1), (1.9, 2.0), (2.0, 2.2)) == "prior"


def test_a_tie_of_candidates_keeps_the_simpler() -> None:
    """Two candidates both far better than the prior and within the noise of each other: the
    one with fewer parameters (torque+scale, 2, against duty, 3)."""
    assert _choose((40, 40), (3.0, 3.0), (3.3, 3.2)) == "torque+scale"


def _off(block: Replayed, factor: float = 1.0, move: int = -1, counts: float = 0.0) -> Replayed:
    """``block`` with joint 2's divergence scaled by ``factor`` and ``counts`` more through
    ``move``."""
    diff = block.diff_counts.copy()
    diff[:, 1] *= factor
    diff[block.window == move, 1] += counts
    return replace(block, diff_counts=diff)


def test_a_shared_structure_needs_more_than_one_move() -> None:
    """The stop rule changes every joint at once. On a joint neither twin predicts (50 counts
    off, a step loss the prior lacks) the two rules may put one move 300 counts apart in one
    block, and another 60 apart the other way in the other: no evidence, the prior kept. The
    same joint a tenth closer on every move of both blocks is evidence: kept."""
    mine = [_block(50, 1), _off(_block(50, 2), move=7, counts=60.0)]
    without = [_off(_block(50, 1), move=3, counts=300.0), _block(50, 2)]
    assert shared_verdict(mine, without, need_better=True) == ([], False)
    closer = [_off(b, factor=0.9) for b in without]
    assert shared_verdict(closer, without, need_better=True) == ([], True)
    # a value that need not be better (the Hall positions) is kept unless a joint is worse
    assert shared_verdict(mine, without, need_better=False) == ([], True)
    assert shared_verdict(without, closer, need_better=False) == ([2], True)


def test_worse_at_the_end_of_the_session_is_out() -> None:
    """A candidate far better than the prior on the first block but worse on the end block
    (an arm whose behaviour moved during the session: fitted as a constant, it no longer
    holds): it is out, and the prior is kept."""
    assert _choose((20, 5), (1.0, 25), (30, 30)) == "prior"


def test_an_arm_that_moved_during_the_session_keeps_the_prior() -> None:
    """The duty law fitted to the session is 30 counts ahead of the arm along the motion on the
    block after the approaches (the arm lost fewer steps then) and 30 behind at the end (it
    loses more now: its drives warmed up), and better than the prior (100) on both: a constant
    fitted to the session predicts neither, the prior is kept and the reason says why. Ahead
    on both blocks (a share a little off) is no sign of it."""
    scores = [[_block(100, 1), _block(100, 2)], [_block(1, 3, lead=30),
                                                 _block(1, 4, lead=-30)],
              [_block(110, 5), _block(110, 6)]]
    choice = decide(1, NAMES, SIZES, scores, ["suite", "end"])
    assert choice.kept == "prior", choice.why
    assert "moved during the session" in choice.why and "duty is ahead" in choice.why
    steady = [[_block(100, 1), _block(100, 2)], [_block(1, 3, lead=30),
                                                 _block(1, 4, lead=25)],
              [_block(110, 5), _block(110, 6)]]
    assert decide(1, NAMES, SIZES, steady, ["suite", "end"]).kept == "duty"


def test_a_lead_within_the_timing_of_moving_replies_is_no_drift() -> None:
    """On a loaded host the replies' timing scatters by milliseconds: where the joint moves a
    perfect twin is a few counts ahead or behind (the floor there, 12 counts), though the floor
    over the whole block, mostly at rest, is 2. A candidate 8 counts ahead on one block and 5
    behind on the other is within that timing: it is kept. 30 each way is beyond it."""
    within = [[_block(100, 1), _block(100, 2)],
              [_block(1, 3, lead=8, moving_floor=12), _block(1, 4, lead=-5, moving_floor=12)],
              [_block(110, 5), _block(110, 6)]]
    assert decide(1, NAMES, SIZES, within, ["suite", "end"]).kept == "duty"
    beyond = [[_block(100, 1), _block(100, 2)],
              [_block(1, 3, lead=30, moving_floor=12), _block(1, 4, lead=-30, moving_floor=12)],
              [_block(110, 5), _block(110, 6)]]
    choice = decide(1, NAMES, SIZES, beyond, ["suite", "end"])
    assert choice.kept == "prior" and "moved during the session" in choice.why, choice.why


def _two_moves(seed: int, leads: tuple[float, float]) -> Replayed:
    """A block of two moves (the first and second half of :func:`_block`'s), the twin ahead of
    the arm along the motion by ``leads[k]`` counts in move ``k``; floor 2 everywhere."""
    block = _block(1, seed)
    window = (block.window >= MOVES // 2).astype(np.int64)
    diff = block.diff_counts.copy()
    diff[:, 1] -= np.asarray(leads)[window] * block.way[:, 1]
    return replace(block, diff_counts=diff, window=window)


def test_a_lead_that_one_move_carries_is_no_drift() -> None:
    """Two moves a block, as a short budget holds (the shared arm's j4 in CI): the twin on
    time in one move and 14 counts ahead in the other (7 on the block's average), then on
    time and 10 behind (5): one move of a loaded host's carries it, and the moves' scatter
    says so; the fitted law is kept. Ahead in both moves of one block and behind in both of
    the other is drift: the prior is kept."""
    one_move = [[_block(100, 1), _block(100, 2)],
                [_two_moves(3, (0.0, 14.0)), _two_moves(4, (0.0, -10.0))],
                [_block(110, 5), _block(110, 6)]]
    assert decide(1, NAMES, SIZES, one_move, ["suite", "end"]).kept == "duty"
    both = [[_block(100, 1), _block(100, 2)],
            [_two_moves(3, (7.0, 7.0)), _two_moves(4, (-5.0, -5.0))],
            [_block(110, 5), _block(110, 6)]]
    choice = decide(1, NAMES, SIZES, both, ["suite", "end"])
    assert choice.kept == "prior" and "moved during the session" in choice.why, choice.why


def test_better_at_the_end_and_worse_after_the_approaches_keeps_the_prior() -> None:
    """The drift arm's joint 3 in CI (its losses grow by half of themselves each 20 s): the
    torque law 888 counts RMS on the block after the approaches against the prior's 859 (worse,
    within the moves' scatter) and 955 at the end against 1540 (better by far). The blocks hold
    the same motions, so the law fits a moment of the session: the prior is kept, and the
    reason names both blocks. Better on both is kept."""
    scores = [[_block(859, 1), _block(1540, 2)], [_block(888, 3), _block(955, 4)],
              [_block(1100, 5), _block(1600, 6)]]
    choice = decide(1, NAMES, SIZES, scores, ["suite", "end"])
    assert choice.kept == "prior" and "moved during the session" in choice.why, choice.why
    assert "better than the prior on the end block" in choice.why
    assert "worse on the suite block" in choice.why
    scores[1][0] = _block(820, 7)
    assert decide(1, NAMES, SIZES, scores, ["suite", "end"]).kept == "duty"


def test_a_win_one_move_carries_does_not_outweigh_a_loss_on_the_other_block() -> None:
    """The drift arm's joint 3 in a later CI run: the torque law 918 counts RMS after the
    approaches against the prior's 887 (worse, within the moves' scatter), and better at the
    end only through one move the prior got wrong by far (so not beyond the moves' scatter
    either). On the held-out run it was 724 against the default twin's 629. Each block's
    verdict beyond its floor disagrees: the prior is kept. The same win with no loss on the
    other block is kept (a step loss in one move, the stall law's case)."""
    prior_end = _off(_block(800, 2), move=7, counts=5650.0)
    scores = [[_block(887, 1), prior_end], [_block(918, 3), _block(800, 2)],
              [_block(1100, 5), _block(1600, 6)]]
    choice = decide(1, NAMES, SIZES, scores, ["suite", "end"])
    assert choice.kept == "prior" and "moved during the session" in choice.why, choice.why
    assert "better than the prior on the end block beyond its floor" in choice.why
    scores[1][0] = scores[0][0]
    assert decide(1, NAMES, SIZES, scores, ["suite", "end"]).kept == "duty"


def test_a_structure_that_explains_only_the_start_keeps_the_prior() -> None:
    """The duty law explains the block after the approaches (3 counts against the prior's 300)
    and not the end block (250 against 300: the arm loses far more by then), though better
    than the prior on both: the arm changed during the session, the prior is kept. One that
    explains both is kept."""
    scores = [[_block(300, 1), _block(300, 2)], [_block(3, 3), _block(250, 4)],
              [_block(280, 5), _block(320, 6)]]
    choice = decide(1, NAMES, SIZES, scores, ["suite", "end"])
    assert choice.kept == "prior" and "explains the suite block" in choice.why, choice.why
    assert "not the end block" in choice.why
    scores[1][1] = _block(4, 7)
    assert decide(1, NAMES, SIZES, scores, ["suite", "end"]).kept == "duty"


def test_the_suites_motions_are_held_out_within_the_budget(tmp_path: Path) -> None:
    """On the emulator with a budget of 120 s: a block of the suites' motions after the
    approaches and one at the end, each within its share of the budget (a quarter beyond, for
    stalls held and sent again), their windows in the session's capture, which holds their
    commands; the robot time within the budget; the settings file and the page say per joint
    what was kept and why."""
    out = tmp_path / "robot.toml"
    result = run_virtual(calibrate_port("fake://", RobotSettings(), out, budget_s=120.0,
                                        page=render_page))
    obs = result.observations
    assert obs.robot_time_s <= 120.0
    assert [b.name for b in obs.held_out] == ["suite", "end"]
    # the emulator has a truth source: its holds come first, from the approaches' last pose
    assert obs.phases_done[-1] == "end" and obs.phases_done[:4] == ["timing", "approaches",
                                                                    "holds", "suite"]
    for b in obs.held_out:
        assert 0.0 < b.end_s - b.start_s <= 1.25 * BLOCK_SHARE * 120.0 + 1.0, b
    records = [json.loads(line) for line in Path(obs.capture or "").read_text().splitlines()]
    sent = [r["t_s"] for r in records if r["dir"] == "out"]
    for b in obs.held_out:
        assert sum(b.start_s <= t <= b.end_s for t in sent) >= 3, b
    assert [c["joint"] for c in result.held_out] == [1, 2, 3, 4]
    text = out.read_text()
    for j in range(1, 5):
        assert f"# speed model of j{j}: " in text
    assert "held out (suite / end: " in text
    page = out.with_suffix(".html").read_text()
    assert "Speed models judged on the held-out blocks" in page and "<td>j4</td>" in page
