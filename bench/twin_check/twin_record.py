"""The record of ``armbench twin-check --out DIR``: a run record (``results.json``, schema
``armbench-run/1``, written by :class:`~armbench.record.RecordWriter`) holding one suite,
``twin-check``, so ``armbench report``, ``compare``, ``report --index`` and ``--baseline`` read it
like any run's.

The suite (names from :data:`~armbench.bench.suites.twin_check_contract.TWIN_CHECK`) holds:

* its parameters: the inputs (capture, settings and limits files, each with its SHA-256) and the
  number of buckets the series were kept with;
* its measurements: exactly the check's (:attr:`TwinCheck.measurements`, what ``--json`` prints);
* one trial spanning the compared replies (on the capture's clock) whose samples are the overlay:
  per joint, at the kept replies, the arm's and the twin's reported angle and their divergence in
  counts, kept as a min/max envelope of the three series (:func:`envelope_indices`), so a
  divergence spike survives; and per move both streams arrived at, the two arrival delays and
  their difference, kept the same way on the difference.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np

from armbench.bench.runner.options import JUNIT_FILE
from armbench.bench.runner.outputs import check_out_dir as check_out_dir_writable
from armbench.bench.suites.twin_check_contract import TWIN_CHECK
from armbench.bench.twin_check.check import Aligned, TwinCheck
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.metrics.series import envelope_indices
from armbench.record import (
    CAPTURE_FILE,
    JOURNAL_FILE,
    REPORT_FILE,
    RESULTS_FILE,
    Measurement,
    RecordError,
    RecordWriter,
    RunRecord,
    Trial,
    capture_environment,
    path_inside,
)
from armbench.record.limits import LimitsConfig
from armbench.record.suite_contract import RAD_DECIMALS, SAMPLE

__all__ = ["ARRIVAL_BUCKETS", "SERIES_BUCKETS", "VERSION", "TwinInputs", "check_out_dir",
           "file_sha256", "twin_record", "write_twin_record"]

#: The suite's version in the record (its figures and samples as described above).
VERSION: Final = "2"
#: Buckets of each joint's kept series: at most 2 × 3 points per bucket (the lowest and highest
#: of the arm's angle, the twin's and their divergence), so at most 1200 points per joint.
SERIES_BUCKETS: Final = 200
#: Buckets of the kept arrival rows (the lowest and highest difference of each).
ARRIVAL_BUCKETS: Final = 200
#: Decimal places of a divergence in counts and of an arrival time (s) in the samples.
COUNT_DECIMALS: Final = 4
TIME_DECIMALS: Final = 6


@dataclass(frozen=True, slots=True)
class TwinInputs:
    """What a check read: the capture, the twin's settings file (None: the default arm) and the
    limits file."""

    capture: Path
    settings: Path | None
    config: Path


def file_sha256(path: Path) -> str:
    """The SHA-256 of a file's bytes (hex), read in chunks."""
    digest = hashlib.sha256()
    try:
        with path.open("rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                digest.update(chunk)
    except OSError as exc:
        raise ArmbenchError(f"{path}: cannot be read: {exc.strerror or exc}") from None
    return digest.hexdigest()


#: What ``--out DIR`` receives: the record, its pages; a capture there would get the report
#: attached (``armbench.cli.commands.run_files``), and a run's journal means a run's directory.
OUT_FILES: Final = (RESULTS_FILE, JOURNAL_FILE, REPORT_FILE, JUNIT_FILE, CAPTURE_FILE)


def check_out_dir(out_dir: Path) -> None:
    """Refuse, before the replay, a directory that already holds a record (a run's record is
    never overwritten by a check) or any file the check writes or touches, and one that cannot
    be written (a file in the way, a read-only file system:
    :mod:`armbench.bench.runner.outputs`)."""
    if out_dir.is_dir():
        results = path_inside(out_dir, RESULTS_FILE)
        if results.exists():
            raise RecordError(str(results), "already holds a run record; choose another "
                                            "directory")
    check_out_dir_writable("--out", out_dir, OUT_FILES)


def _series_samples(series: Aligned) -> list[dict[str, Any]]:
    n = TWIN_CHECK
    div = series.divergence_counts
    out: list[dict[str, Any]] = []
    for j in range(series.arm_rad.shape[1]):
        kept = envelope_indices(np.column_stack([series.arm_rad[:, j], series.twin_rad[:, j],
                                                 div[:, j]]), SERIES_BUCKETS)
        out.extend({SAMPLE.kind: n.series_kind, n.joint: j + 1,
                    SAMPLE.t: round(float(series.t_s[i]), TIME_DECIMALS),
                    n.arm: round(float(series.arm_rad[i, j]), RAD_DECIMALS),
                    n.twin: round(float(series.twin_rad[i, j]), RAD_DECIMALS),
                    n.divergence: round(float(div[i, j]), COUNT_DECIMALS)} for i in kept)
    return out


def _arrival_samples(arrivals: list[tuple[float, float | None, float | None]]
                     ) -> list[dict[str, Any]]:
    n = TWIN_CHECK
    both = [(t, a, b) for t, a, b in arrivals if a is not None and b is not None]
    if not both:
        return []
    kept = envelope_indices(np.asarray([b - a for _, a, b in both]), ARRIVAL_BUCKETS)
    return [{SAMPLE.kind: n.arrival_kind, SAMPLE.t: round(t, TIME_DECIMALS),
             n.arm_arrival: round(a - t, TIME_DECIMALS),
             n.twin_arrival: round(b - t, TIME_DECIMALS),
             n.arrival_dt: round(b - a, TIME_DECIMALS)}
            for t, a, b in (both[int(i)] for i in kept)]


def twin_record(result: TwinCheck, inputs: TwinInputs, settings: RobotSettings,
                limits: LimitsConfig) -> tuple[RunRecord, dict[str, Any], Trial,
                                               list[Measurement]]:
    """The record's parts: a new record (environment: the twin as a ``fake://`` port, its
    settings and seed, the limits), the suite's parameters, its trial and its measurements."""
    n = TWIN_CHECK
    port = "fake://" + ("" if inputs.settings is None else f"?settings={inputs.settings}")
    env = capture_environment(port=port, settings=settings,
                              seed=emulator_settings(settings).seed, limits=limits)
    record = RunRecord.new(env, [n.suite])
    params: dict[str, Any] = {
        n.capture: str(inputs.capture), n.capture_sha256: file_sha256(inputs.capture),
        n.settings: None if inputs.settings is None else str(inputs.settings),
        n.settings_sha256: None if inputs.settings is None else file_sha256(inputs.settings),
        n.config: str(inputs.config), n.config_sha256: file_sha256(inputs.config),
        n.buckets: SERIES_BUCKETS,
    }
    samples = [] if result.series is None else _series_samples(result.series)
    samples += _arrival_samples(result.arrivals)
    t_s = np.zeros(0) if result.series is None else result.series.t_s
    span_s = float(t_s[-1] - t_s[0]) if len(t_s) > 1 else 0.0
    trial = Trial(0, 0.0, span_s, {n.sessions: result.sessions}, samples)
    return record, params, trial, list(result.measurements)


def write_twin_record(result: TwinCheck, inputs: TwinInputs, settings: RobotSettings,
                      limits: LimitsConfig, out_dir: Path) -> RunRecord:
    """Write the check's record to ``out_dir/results.json`` (and nothing else); returns it. The
    run clock is the capture's: the suite spans the compared replies."""
    record, params, trial, measurements = twin_record(result, inputs, settings, limits)
    writer = RecordWriter(out_dir, record)
    writer.begin_suite(TWIN_CHECK.suite, VERSION, params, started_s=0.0)
    writer.add_trial(TWIN_CHECK.suite, trial)
    writer.end_suite(TWIN_CHECK.suite, measurements, ended_s=trial.ended_s)
    return writer.record
