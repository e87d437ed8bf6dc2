"""What a calibration writes: the settings file (every fitted value with its standard error as a
comment beside it), the fit as JSON, and the calibration page (HTML in the report's style).

The settings file is a complete robot settings TOML: ``--settings robot.toml`` and
``fake://?settings=robot.toml`` load it. Fitted values enter it clamped to the documented range of
their setting (a play estimated at −0.001° is written as 0); the JSON keeps the raw estimates.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import jinja2
import numpy as np
from markupsafe import Markup
from matplotlib.figure import Figure

from armbench.bench.calibrate.model import Fitted, Observations
from armbench.bench.calibrate.sensitivity import Sensitivity
from armbench.bench.outputs import OutputError, is_run_file
from armbench.drivers.settings import RobotSettings
from armbench.fakes.physics import ARM_RANGES, JOINT_RANGES
from armbench.record.files import atomic_write_bytes
from armbench.reports.format import jinja_environment
from armbench.reports.plots import to_svg

__all__ = ["CalibrationResult", "apply_fit", "output_paths", "render_page", "toml_text",
           "write_outputs", "written_value"]

_BARE_KEY: Final = re.compile(r"[A-Za-z0-9_-]+")
#: What a calibration without a reference instrument cannot tell (the header and the page say it).
NO_TRUTH: Final = ("the link-side figures (gear play, stick-slip, Hall position errors, "
                   "stiffness, DH lengths and joint offsets) are the prior's and cannot be "
                   "trusted beyond it; give a reference instrument with --tracker to identify "
                   "them")
_HERE: Final = Path(__file__).resolve().parent


@dataclass(frozen=True, slots=True)
class CalibrationResult:
    """A finished (or partial) calibration: what was measured, what was fitted, the settings."""

    observations: Observations
    fitted: list[Fitted]
    settings: RobotSettings
    error: str | None = None
    sensitivity: Sensitivity | None = None


def _range_of(key: str) -> tuple[float, float] | None:
    """Documented range of a settings key, in the key's unit."""
    name = key.rsplit(".", 1)[-1]
    if ".geometry_error." in key:
        return ARM_RANGES["geometry_error_m"]
    attr = name.removesuffix("_deg") + "_rad" if name.endswith("_deg") else name
    rng = JOINT_RANGES.get(attr)
    if rng is None:
        return None
    if name.endswith("_deg"):
        return math.degrees(rng[0]), math.degrees(rng[1])
    return rng


def apply_fit(base: RobotSettings, fitted: Sequence[Fitted]) -> RobotSettings:
    """``base`` with every identified ``emulator.*`` and ``joints.*`` value set and the physical
    profile. A value outside the documented range of its setting is written as fitted (its
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
    return RobotSettings.from_mapping(data)


def written_value(f: Fitted) -> float:
    """The value the settings file gets for ``f``: the fitted one, within the band the settings
    loader accepts around the documented range (ten times wider; five for angles and lengths).
    Plays and bands below 0 become 0 (a width cannot be negative)."""
    value = f.value
    rng = _range_of(f.key)
    if rng is None:
        return value
    low, high = rng
    wide = 5.0 if f.key.endswith(("_deg", "_m")) else 10.0
    if f.key.endswith(("backlash_deg", "stick_deg")):
        return min(max(value, 0.0), high * wide)
    band_low = low * wide if low < 0 else low / wide
    return min(max(value, band_low), high * wide)


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
    as they are measured (``.observations.json``)."""
    paths = [out, out.with_suffix(".json"), out.with_suffix(".html")]
    return [*paths, out.with_suffix(".observations.json")] if observations else paths


def _write(path: Path, text: str) -> None:
    """Replace ``path`` atomically with ``text``; never a file of a run's record."""
    if is_run_file(path):
        raise OutputError("--out", path, "belongs to the run record in its directory; it is "
                                         "never overwritten")
    atomic_write_bytes(path, text.encode("utf-8"))


def write_outputs(result: CalibrationResult, out: Path) -> dict[str, Path]:
    """Write ``out`` (settings TOML), ``out`` with ``.json`` (the fit) and ``.html`` (the page),
    each replaced atomically (a reader sees the old file or the new one); returns the paths by
    kind."""
    out = Path(out)
    comments = {f.key: _sigma_text(f) for f in result.fitted}
    header = (f"Robot settings fitted by armbench calibrate from {result.observations.source}.\n"
              "Each fitted value carries its standard error in the comment beside it; "
              "values the data did not\ndetermine keep the prior and say why. "
              "See docs/calibration.md and the .html page beside this file.")
    if result.error:
        header += f"\nPARTIAL: {result.error}"
    if not result.observations.truth:
        header += f"\nNO REFERENCE INSTRUMENT: {NO_TRUTH}"
    for f in result.fitted:
        if not f.written and not f.key.startswith("timing."):
            shown = f.choice if f.choice is not None else f"{f.value:.6g} {f.unit}"
            header += f"\nkept: {f.key} = {shown} ({f.reason})"
    timing = [f for f in result.fitted if f.key.startswith("timing.") and f.identified]
    for f in timing:
        header += f"\n{f.key} = {f.value:.6g} {f.unit} ± {f.sigma:.2g} (measured)"
    settings_path, fit_path, page = output_paths(out, observations=False)
    _write(settings_path, toml_text(result.settings.to_mapping(), comments, header))
    _write(fit_path, json.dumps({
        "source": result.observations.source, "error": result.error,
        "fitted": [f.to_json() for f in result.fitted],
        "sensitivity": None if result.sensitivity is None else result.sensitivity.to_json(),
        "observations": result.observations.to_json()}, indent=1) + "\n")
    _write(page, render_page(result))
    return {"settings": settings_path, "fit": fit_path, "page": page}


def _figures(result: CalibrationResult) -> list[tuple[str, Markup]]:
    obs = result.observations
    out: list[tuple[str, Markup]] = []
    if obs.speeds:
        fig = Figure(figsize=(7.5, 3.2))
        ax = fig.add_subplot(1, 1, 1)
        for joint in sorted({s.joint for s in obs.speeds}):
            for direction, marker in ((1, "^"), (-1, "v")):
                pts = [(s.duty, s.ratio) for s in obs.speeds
                       if s.joint == joint and s.direction == direction]
                if pts:
                    a = np.asarray(sorted(pts))
                    ax.plot(a[:, 0], a[:, 1], marker=marker, label=f"j{joint} {direction:+d}")
        ax.set_xlabel("duty")
        ax.set_ylabel("effective / law (12) speed")
        ax.legend(fontsize=7, ncol=4)
        fig.subplots_adjust(left=0.1, right=0.98, bottom=0.16, top=0.95)
        out.append(("Effective speed against duty and direction (1 = no step lost)",
                    to_svg(fig, "speed", "effective speed against duty")))
    play = [(ap.joint, ap.direction, ap.link_rad[ap.joint - 1] - ap.motor_rad[ap.joint - 1])
            for ap in obs.approaches if ap.link_rad is not None and ap.motor_rad is not None]
    if play:
        fig = Figure(figsize=(7.5, 3.0))
        ax = fig.add_subplot(1, 1, 1)
        for joint, direction, gap_rad in play:
            ax.plot(joint + 0.1 * direction, math.degrees(gap_rad),
                    "^" if direction > 0 else "v", color="C0" if direction > 0 else "C3")
        ax.set_xticks([1, 2, 3, 4], ["j1", "j2", "j3", "j4"])
        ax.set_ylabel("link − motor (deg)")
        fig.subplots_adjust(left=0.12, right=0.98, bottom=0.12, top=0.95)
        out.append(("Approaches: link against motor, moving + (▲) and − (▼): the gap between "
                    "the groups is the play, their spread the stick-slip band",
                    to_svg(fig, "play", "link against motor per approach")))
    return out


def _kinematic_residuals_mm(result: CalibrationResult) -> list[float]:
    from armbench.drivers.kinematics import tcp_position
    from armbench.fakes.settings import actual_robot, emulator_settings

    if emulator_settings(result.settings).physics is None:
        return []
    actual = actual_robot(result.settings)
    return [float(np.linalg.norm(tcp_position(h.true_rad, actual) - np.asarray(h.tcp_true_m)))
            * 1000.0 for h in result.observations.holds
            if h.true_rad is not None and h.tcp_true_m is not None]


def render_page(result: CalibrationResult) -> str:
    """The calibration page: a self-contained HTML document (no script, nothing fetched)."""
    base = jinja_environment()
    env = base.overlay(loader=jinja2.ChoiceLoader([jinja2.FileSystemLoader(_HERE),
                                                    base.loader or jinja2.BaseLoader()]))
    template = env.get_template("calibration.html.j2")
    return template.render(
        obs=result.observations, error=result.error, NO_TRUTH=NO_TRUTH,
        sensitivity=result.sensitivity,
        identified=[f for f in result.fitted if f.identified],
        kept=[f for f in result.fitted if not f.identified],
        figures=_figures(result), kinematic_mm=_kinematic_residuals_mm(result),
        speeds=sorted(result.observations.speeds, key=lambda s: (s.joint, s.direction, -s.duty)))
