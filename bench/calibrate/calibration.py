"""A whole calibration: measure on a port (or read a capture), fit, write the outputs.

Results already measured stay on disk: the observations are saved after every unit of work, and
when a joint does not move the fit of what was measured is written before the error is raised.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from armbench.bench.calibrate.capture_data import load_capture, observations_from_capture
from armbench.bench.calibrate.fit import chosen_structures, fit_all
from armbench.bench.calibrate.model import ArmDoesNotMoveError, Observations
from armbench.bench.calibrate.output import (
    CalibrationResult,
    PageRenderer,
    apply_fit,
    kinematic_residuals_mm,
    write_outputs,
)
from armbench.bench.calibrate.procedure import DEFAULT_BUDGET_S, Procedure
from armbench.bench.calibrate.sensitivity import sensitivity
from armbench.bench.runner.truth import aclose_source, aopen_source
from armbench.bench.suites.base import PoseSource
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.settings import RobotSettings

__all__ = ["calibrate_capture", "calibrate_port", "finish"]


def finish(obs: Observations, base: RobotSettings, out: Path,
           error: str | None = None, *, page: PageRenderer | None = None) -> CalibrationResult:
    """Fit ``obs``, write the settings, the fit and (rendered by ``page``) the page next to
    ``out``."""
    fitted = fit_all(obs, base)
    structures = chosen_structures(fitted)
    settings = apply_fit(base, fitted)
    result = CalibrationResult(obs, fitted, settings, error,
                               sensitivity(obs, base, fitted,
                                           lambda o, b: fit_all(o, b, structures)),
                               kinematic_residuals_mm(settings, obs))
    write_outputs(result, out, page)
    return result


async def calibrate_port(port: str, base: RobotSettings, out: Path, *,
                         budget_s: float = DEFAULT_BUDGET_S,
                         progress: Callable[[str], None] = lambda message: None,
                         tracker: PoseSource | None = None,
                         page: PageRenderer | None = None,
                         reply_timeout_s: float = 0.5) -> CalibrationResult:
    """Run the procedure on ``port`` and write the outputs. ``reply_timeout_s``: the longest
    silence of the arm tolerated (the driver's). ``tracker``: a reference instrument
    (``--tracker``, ``bench/runner/truth.py``) measuring the true joints and TCP at rest, opened and
    closed around the procedure. ``page`` renders the calibration page (without it none is
    written). A joint that does not move ends the procedure: what was measured is fitted and
    written, then :class:`ArmDoesNotMoveError` is raised."""
    out = Path(out)
    obs = Observations(source=port)
    raw = out.with_suffix(".observations.json")
    failure: ArmDoesNotMoveError | None = None
    if tracker is not None:
        await aopen_source(tracker)
    try:
        async with Arm.connect(port, base, reply_timeout_s=reply_timeout_s) as arm:
            # the outputs' folder once the arm answered: a wrong port leaves nothing behind
            out.parent.mkdir(parents=True, exist_ok=True)
            procedure = Procedure(arm, base, obs, budget_s=budget_s, save=lambda: obs.save(raw),
                                  progress=progress, tracker=tracker)
            try:
                await procedure.run()
            except ArmDoesNotMoveError as exc:
                failure = exc
                obs.error = str(exc)
            obs.save(raw)
    finally:
        if tracker is not None:
            await aclose_source(tracker)
    result = finish(obs, base, out, obs.error, page=page)
    if failure is not None:
        raise failure
    return result


def calibrate_capture(capture: str | Path, base: RobotSettings, out: Path, *,
                      page: PageRenderer | None = None) -> CalibrationResult:
    """Fit what the traffic of an existing capture shows and write the outputs (the page when
    ``page`` renders it)."""
    data = load_capture(capture, base)
    obs = observations_from_capture(data, base)
    return finish(obs, base, Path(out), page=page)
