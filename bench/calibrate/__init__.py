"""``armbench calibrate``: identify the robot model of an arm from its own traffic (and a truth
source where there is one), with the uncertainty of every fitted value."""

from armbench.bench.calibrate.calibration import calibrate_capture, calibrate_port
from armbench.bench.calibrate.capture_data import (
    CaptureData,
    load_capture,
    observations_from_capture,
)
from armbench.bench.calibrate.fit import fit_all
from armbench.bench.calibrate.model import (
    ArmDoesNotMoveError,
    CalibrationError,
    CaptureContentError,
    Fitted,
    Observations,
)
from armbench.bench.calibrate.output import CalibrationResult, apply_fit, write_outputs
from armbench.bench.calibrate.procedure import DEFAULT_BUDGET_S, Procedure

__all__ = [
    "DEFAULT_BUDGET_S",
    "ArmDoesNotMoveError",
    "CalibrationError",
    "CalibrationResult",
    "CaptureContentError",
    "CaptureData",
    "Fitted",
    "Observations",
    "Procedure",
    "apply_fit",
    "calibrate_capture",
    "calibrate_port",
    "fit_all",
    "load_capture",
    "observations_from_capture",
    "write_outputs",
]
