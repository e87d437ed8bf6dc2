"""A whole calibration: measure on a port (or read a capture), fit, judge the fit on the held-out
blocks, write the outputs.

Results already measured stay on disk: the observations are saved after every unit of work (and
the session's traffic as it goes, where the held-out blocks are), and when a joint does not move
the fit of what was measured is written before the error is raised.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Final

from armbench.bench.calibrate.capture_data import (
    CaptureData,
    load_capture,
    observations_from_capture,
)
from armbench.bench.calibrate.divergence import arm_side
from armbench.bench.calibrate.fit import chosen_structures, fit_all
from armbench.bench.calibrate.held_out import Block, blocks_of, choose
from armbench.bench.calibrate.model import ArmDoesNotMoveError, Observations, ReferencePose
from armbench.bench.calibrate.output import (
    CalibrationResult,
    PageRenderer,
    apply_fit,
    kinematic_residuals_mm,
    write_outputs,
)
from armbench.bench.calibrate.procedure import DEFAULT_BUDGET_S, Procedure
from armbench.bench.calibrate.reference import Plate
from armbench.bench.calibrate.sensitivity import sensitivity
from armbench.bench.calibrate.structure import SpeedOption
from armbench.bench.calibrate.touch_off import Operator, touch_off
from armbench.bench.runner.truth import aclose_source, aopen_source
from armbench.bench.suites.base import PoseSource
from armbench.drivers.capture.jsonl import CaptureWriter
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.settings import RobotSettings

__all__ = ["CAPTURE_MAX_BYTES", "END_SHARE", "calibrate_capture", "calibrate_port",
           "calibrate_reference", "finish"]

#: Bound of the session's capture (bytes): a 15-minute session at 200 replies a second takes
#: about 11 MB.
CAPTURE_MAX_BYTES: Final = 256 * 1024 * 1024
#: Of an existing capture (``--capture``), the share of its commands at its end held out.
END_SHARE: Final = 0.3


def finish(obs: Observations, base: RobotSettings, out: Path,
           error: str | None = None, *, page: PageRenderer | None = None,
           blocks: Sequence[Block] = ()) -> CalibrationResult:
    """Fit ``obs``, keep of it what the held-out ``blocks`` support
    (:func:`armbench.bench.calibrate.held_out.choose`; the blocks of a session on a port come
    after its approaches, which cross every Hall sensor), write the settings, the fit and
    (rendered by ``page``) the page next to ``out``. Replays the blocks on virtual-time loops
    of its own: call it where no loop runs (a worker thread)."""
    options: dict[int, list[SpeedOption]] = {}
    crossed = True if "approaches" in obs.phases_done else None
    fitted, choices = choose(fit_all(obs, base, options=options), base, options, blocks,
                             crossed)
    structures = chosen_structures(fitted)
    settings = apply_fit(base, fitted)
    result = CalibrationResult(obs, fitted, settings, error,
                               sensitivity(obs, base, fitted,
                                           lambda o, b: fit_all(o, b, structures)),
                               kinematic_residuals_mm(settings, obs),
                               tuple(c.to_json() for c in choices))
    write_outputs(result, out, page)
    return result


def _session_blocks(obs: Observations, base: RobotSettings) -> list[Block]:
    """The held-out blocks of a session on a port, from its capture."""
    if obs.capture is None or not obs.held_out:
        return []
    return blocks_of(load_capture(obs.capture, base), obs.held_out)


async def calibrate_port(port: str, base: RobotSettings, out: Path, *,
                         budget_s: float = DEFAULT_BUDGET_S,
                         progress: Callable[[str], None] = lambda message: None,
                         tracker: PoseSource | None = None,
                         page: PageRenderer | None = None,
                         reply_timeout_s: float = 0.5,
                         references: Sequence[ReferencePose] = (),
                         touch: tuple[Plate, Operator] | None = None) -> CalibrationResult:
    """Run the procedure on ``port`` and write the outputs. ``reply_timeout_s``: the longest
    silence of the arm tolerated (the driver's). ``tracker``: a reference instrument
    (``--tracker``, ``bench/runner/truth.py``) measuring the true joints and TCP at rest, opened and
    closed around the procedure. ``references``: tool positions a lab measured (``--reference``);
    ``touch``: a plate and its operator, who touches its points after the procedure
    (``--touch-off``, not counted in the budget: the operator sets the pace). ``page`` renders
    the calibration page (without it none is written). The session's traffic is captured beside
    ``out`` (``.capture.jsonl``): its held-out blocks judge the fit. A joint that does not move
    ends the procedure: what was measured is fitted and written, then
    :class:`ArmDoesNotMoveError` is raised."""
    out = Path(out)
    obs = Observations(source=port, references=list(references))
    raw = out.with_suffix(".observations.json")
    failure: ArmDoesNotMoveError | None = None
    if tracker is not None:
        await aopen_source(tracker)
    made = not out.parent.exists()
    out.parent.mkdir(parents=True, exist_ok=True)
    capture = CaptureWriter(out.with_suffix(".capture.jsonl"), asyncio.get_running_loop().time(),
                            max_bytes=CAPTURE_MAX_BYTES)
    answered = False
    try:
        async with Arm.connect(port, base, reply_timeout_s=reply_timeout_s,
                               capture=capture) as arm:
            answered = True
            obs.capture = str(capture.path)
            procedure = Procedure(arm, base, obs, budget_s=budget_s, save=lambda: obs.save(raw),
                                  progress=progress, tracker=tracker,
                                  capture_origin_s=capture.t0_s)
            try:
                await procedure.run()
            except ArmDoesNotMoveError as exc:
                failure = exc
                obs.error = str(exc)
            obs.save(raw)
            if touch is not None and failure is None:
                obs.references += await touch_off(arm, touch[0], touch[1], progress)
                obs.save(raw)
    finally:
        capture.close()
        if not answered:  # a wrong port leaves nothing behind
            capture.path.unlink(missing_ok=True)
            if made:
                out.parent.rmdir()
        if tracker is not None:
            await aclose_source(tracker)
    progress("calibrate: fitting, and judging the fit on the held-out blocks")
    blocks = _session_blocks(obs, base)
    result = await asyncio.to_thread(finish, obs, base, out, obs.error, page=page,
                                     blocks=blocks)
    if failure is not None:
        raise failure
    return result


def _split(data: CaptureData) -> tuple[CaptureData, list[Block]]:
    """An existing capture as the part fitted and the end held out (:data:`END_SHARE` of its
    commands, at least one; none when that leaves fewer than two to fit)."""
    n = len(data.commands)
    k = n - max(1, round(END_SHARE * n))
    if k < 2:
        return data, []
    t = data.commands[k][0]
    fitted = CaptureData(data.path, data.commands[:k], [r for r in data.replies if r[0] < t],
                         data.bad_in_frames)
    end = CaptureData(data.path, data.commands[k:],
                      [r for r in data.replies if r[0] >= t - 0.1], 0)
    return fitted, [Block("end", end, arm_side(end))]


def calibrate_capture(capture: str | Path, base: RobotSettings, out: Path, *,
                      page: PageRenderer | None = None,
                      references: Sequence[ReferencePose] = ()) -> CalibrationResult:
    """Fit what the traffic of an existing capture shows, its end held out, and the tool
    positions a lab measured (``references``), and write the outputs (the page when ``page``
    renders it)."""
    fitted, blocks = _split(load_capture(capture, base))
    obs = observations_from_capture(fitted, base)
    obs.references = list(references)
    return finish(obs, base, Path(out), page=page, blocks=blocks)


def calibrate_reference(source: str, references: Sequence[ReferencePose], base: RobotSettings,
                        out: Path, *, page: PageRenderer | None = None) -> CalibrationResult:
    """Fit the geometry (DH lengths, offsets, play) of tool positions a lab measured alone
    (``--reference`` without a port or a capture; ``source`` names the file) and write the
    outputs; everything else keeps the prior."""
    obs = Observations(source=source, references=list(references))
    return finish(obs, base, Path(out), page=page)
