"""What a calibration writes: the settings file (every fitted value with its standard error in the
``[uncertainty]`` table, and as a comment beside it for the reader), the fit as JSON, and the
calibration page (HTML in the report's style), which the caller renders (the command line passes
:func:`armbench.reports.pages.calibration_page.render_page`: the report is a layer above the bench,
``docs/architecture.md``).

The settings file is a complete robot settings TOML: ``--settings robot.toml`` and
``fake://?settings=robot.toml`` load it. Fitted values enter it clamped to the band the settings
loader accepts around the documented range of their setting
(:meth:`~armbench.drivers.model.twin_parameters.TwinParameter.accepted`: a play estimated at
−0.001° is written as 0); the JSON keeps the raw estimates.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np

from armbench.bench.calibrate.model import (
    NO_TRUTH,
    CalibrationResult,
    Fitted,
    Observations,
    PageRenderer,
    no_truth,
)
from armbench.bench.runner.outputs import OutputError, is_run_file
from armbench.drivers.model.settings import UNCERTAINTY_TABLE, RobotSettings
from armbench.drivers.model.twin_parameters import by_path
from armbench.record.files import atomic_write_bytes

__all__ = ["NO_TRUTH", "CalibrationResult", "PageRenderer", "apply_fit", "kinematic_residuals_mm",
           "output_paths", "toml_text", "uncertainty_table", "write_outputs", "written_value"]

_BARE_KEY: Final = re.compile(r"[A-Za-z0-9_-]+")



def kinematic_residuals_mm(settings: RobotSettings,
                           observations: Observations) -> tuple[float, ...]:
    """The distance from the TCP the fitted ``settings`` put at each hold's true joint angles to
    the TCP the reference instrument measured (mm); none without the emulator's physics."""
    from armbench.drivers.model.kinematics import tcp_position
    from armbench.fakes.firmware.emulator_settings import actual_robot, emulator_settings

    if emulator_settings(settings).physics is None:
        return ()
    actual = actual_robot(settings)
    return tuple(float(np.linalg.norm(tcp_position(h.true_rad, actual) - np.asarray(h.tcp_true_m)))
                 * 1000.0 for h in observations.holds
                 if h.true_rad is not None and h.tcp_true_m is not None)


def apply_fit(base: RobotSettings, fitted: Sequence[Fitted]) -> RobotSettings:
    """``base`` with every identified ``emulator.*`` and ``joints.*`` value set, the physical
    profile, and the ``[uncertainty]`` table of those values (:func:`uncertain`: it replaces any
    the base had). A value outside the documented range of its setting is written as fitted (its
    comment says so, :func:`written_value`) unless the settings file would refuse it."""
    data = base.to_mapping()
    emulator = data.setdefault("emulator", {})
    emulator["profile"] = "physical"
    for f in fitted:
        if not (f.written and f.key.startswith(("emulator.", "joints."))):
            continue
        parts = f.key.split(".")
        table = data
        for part in parts[:-1]:
            table = table.setdefault(part, {})
        table[parts[-1]] = f.choice if f.choice is not None else written_value(f)
    data.pop(UNCERTAINTY_TABLE, None)
    sigmas = uncertainty_table(fitted)
    if sigmas:
        data[UNCERTAINTY_TABLE] = sigmas
    return RobotSettings.from_mapping(data)


def uncertainty_table(fitted: Sequence[Fitted]) -> dict[str, float]:
    """The settings file's ``[uncertainty]`` table: the standard error of each identified number
    written as fitted (not clamped, not a choice or a bound) of an ``emulator.*`` or ``joints.*``
    setting, by its dotted key."""
    return {f.key: f.sigma for f in fitted
            if f.identified and f.sigma is not None and f.choice is None
            and f.key.startswith(("emulator.", "joints.")) and written_value(f) == f.value}


def written_value(f: Fitted) -> float:
    """The value the settings file gets for ``f``: the fitted one, within the band the settings
    loader accepts around the documented range of its twin parameter (a play below 0 becomes 0:
    a width cannot be negative); a setting of the robot model (a gear ratio) as fitted."""
    p = by_path(f.key)
    if p is None:
        return f.value
    low, high = p.accepted()
    return min(max(f.value, low), high)


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.fullmatch(key) else json.dumps(key)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(float(value))
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}"
                               for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} to TOML")


def toml_text(data: Mapping[str, Any], comments: Mapping[str, str] | None = None,
              header: str = "") -> str:
    """``data`` (a TOML-shaped mapping) as TOML text; ``comments`` maps dotted keys to a comment
    written after the value."""
    notes = comments or {}
    lines: list[str] = [f"# {line}".rstrip() for line in header.splitlines()]

    def table(path: list[str], t: Mapping[str, Any]) -> None:
        scalars = [(k, v) for k, v in t.items() if not isinstance(v, Mapping)]
        if path and (scalars or not t):
            lines.append("")
            lines.append("[" + ".".join(_toml_key(p) for p in path) + "]")
        for k, v in scalars:
            note = notes.get(".".join([*path, k]))
            lines.append(f"{_toml_key(k)} = {_toml_value(v)}" + (f"  # {note}" if note else ""))
        for k, v in t.items():
            if isinstance(v, Mapping):
                table([*path, k], v)

    table([], data)
    return "\n".join(lines).lstrip("\n") + "\n"


def _sigma_text(f: Fitted) -> str:
    written = written_value(f) if f.choice is None else f.value
    if f.choice is None and f.written and written != f.value:
        return (f"CLAMPED from the fit's {f.value:.6g} {f.unit} (± {f.sigma or 0:.3g}), which "
                f"the settings file cannot hold; {f.reason}")
    if f.identified and f.choice is not None:
        return f"chosen: {f.reason}"
    if f.identified and f.sigma is not None:
        return f"fitted: ± {f.sigma:.3g} {f.unit} (1 σ); {f.reason}"
    if f.lower_bound is not None:
        return f"bounded: {f.reason}"
    return f"kept: {f.reason}"


def output_paths(out: Path, *, observations: bool) -> list[Path]:
    """Every file a calibration to ``out`` writes: the settings (``out``), the fit (``.json``),
    the page (``.html``) and, when measuring on a port (``observations``), the observations saved
    as they are measured (``.observations.json``) and the session's capture, where its held-out
    blocks are (``.capture.jsonl``)."""
    paths = [out, out.with_suffix(".json"), out.with_suffix(".html")]
    return [*paths, out.with_suffix(".observations.json"),
            out.with_suffix(".capture.jsonl")] if observations else paths


def _write(path: Path, text: str) -> None:
    """Replace ``path`` atomically with ``text``; never a file of a run's record."""
    if is_run_file(path):
        raise OutputError("--out", path, "belongs to the run record in its directory; it is "
                                         "never overwritten")
    atomic_write_bytes(path, text.encode("utf-8"))


def write_outputs(result: CalibrationResult, out: Path,
                  page: PageRenderer | None = None) -> dict[str, Path]:
    """Write ``out`` (settings TOML), ``out`` with ``.json`` (the fit) and, when ``page`` renders
    it, ``.html`` (the page), each replaced atomically (a reader sees the old file or the new
    one); returns the paths written by kind."""
    out = Path(out)
    comments = {f.key: _sigma_text(f) for f in result.fitted}
    header = (f"Robot settings fitted by armbench calibrate from {result.observations.source}.\n"
              "Each fitted value's standard error (1 σ) is in the [uncertainty] table at the "
              "end, which\ncampaigns draw from, and in the comment beside it; values the data did "
              "not determine keep\nthe prior and say why. "
              "See docs/calibration.md and the .html page beside this file.")
    if result.error:
        header += f"\nPARTIAL: {result.error}"
    if not result.observations.truth:
        header += f"\nNO REFERENCE INSTRUMENT: {no_truth(result.observations)}"
    for choice in result.held_out:
        header += f"\nspeed model of j{choice['joint']}: {choice['why']}"
    for f in result.fitted:
        if not f.written and not f.key.startswith("timing."):
            shown = f.choice if f.choice is not None else f"{f.value:.6g} {f.unit}"
            header += f"\nkept: {f.key} = {shown} ({f.reason})"
    timing = [f for f in result.fitted if f.key.startswith("timing.") and f.identified]
    for f in timing:
        header += f"\n{f.key} = {f.value:.6g} {f.unit} ± {f.sigma:.2g} (measured)"
    settings_path, fit_path, page_path = output_paths(out, observations=False)
    _write(settings_path, toml_text(result.settings.to_mapping(), comments, header))
    _write(fit_path, json.dumps({
        "source": result.observations.source, "error": result.error,
        "fitted": [f.to_json() for f in result.fitted],
        "sensitivity": None if result.sensitivity is None else result.sensitivity.to_json(),
        "held_out": list(result.held_out),
        "observations": result.observations.to_json()}, indent=1) + "\n")
    written = {"settings": settings_path, "fit": fit_path}
    if page is not None:
        _write(page_path, page(result))
        written["page"] = page_path
    return written
