"""Formatting shared by the run report and the run index: numbers, durations, verdict and outcome
markers (a word and a symbol, never colour alone), the Content-Security-Policy and the Jinja2
environment (autoescaping, strict undefined)."""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from pathlib import Path

import jinja2

from armbench.record import Measurement
from armbench.record.suite_contract import resolution

__all__ = [
    "CSP",
    "OUTCOME_MARKS",
    "RESULT_MARKS",
    "VERDICT_MARKS",
    "format_duration",
    "format_number",
    "format_value",
    "jinja_environment",
    "margin",
]

#: The report's Content-Security-Policy (a ``<meta http-equiv>``): nothing may be fetched, no
#: script runs; inline ``<style>``/``style=`` (the page's CSS and matplotlib's SVG) and ``data:``
#: images are all the page needs. ``frame-ancestors`` is left out: browsers ignore it (and complain)
#: in a ``<meta>`` element.
CSP = ("default-src 'none'; style-src 'unsafe-inline'; img-src data:; base-uri 'none'; "
       "form-action 'none'")

#: Verdict -> (symbol, word). Shown together, so the verdict never rests on colour alone.
VERDICT_MARKS: Mapping[str, tuple[str, str]] = {
    "pass": ("✔", "PASS"),
    "fail": ("✘", "FAIL"),
    "regression": ("▼", "REGRESSION"),
    "error": ("⚠", "ERROR"),
    "incomplete": ("◐", "INCOMPLETE"),
    "untested": ("○", "UNTESTED"),
}

#: Measurement outcome -> (symbol, word).
OUTCOME_MARKS: Mapping[str, tuple[str, str]] = {
    "pass": ("✔", "pass"),
    "fail": ("✘", "FAIL"),
    "unjudged": ("○", "unjudged"),
}

#: Baseline comparison result -> (symbol, word), as ``armbench compare`` words them.
RESULT_MARKS: Mapping[str, tuple[str, str]] = {
    "ok": ("=", "ok"),
    "improved": ("★", "improved"),
    "REGRESSED": ("✘", "REGRESSED"),
    "new": ("+", "new"),
    "missing": ("−", "missing"),
}

_TEMPLATES = Path(__file__).resolve().parents[1] / "templates"


def format_number(value: float | None, *, signed: bool = False, unit: str = "") -> str:
    """A figure for people: four significant digits (``12.39``, ``0.31``, ``100``), whole numbers
    from 10 000 up with thousands separators (``33,499``), ``-`` for None, ``+`` on positive
    changes when ``signed``. With a ``unit`` whose resolution is known (samples are rounded, see
    :func:`armbench.record.suite_contract.resolution`) no digit finer than that resolution is
    printed, so a spread below it prints as ``0``, never as ``2.22e-13``. The report and
    ``armbench compare`` agree."""
    if value is None:
        return "-"
    if not math.isfinite(value):
        return str(value)
    step = resolution(unit)
    if step is not None:
        value = round(value, max(0, round(-math.log10(step))))
    if value == 0:
        value = 0.0  # no "-0"
    if abs(value) >= 10_000:
        return f"{value:+,.0f}" if signed else f"{value:,.0f}"
    return f"{value:+.4g}" if signed else f"{value:.4g}"


def format_value(value: float | None, unit: str, *, signed: bool = False) -> str:
    """``format_number`` (at the unit's resolution) followed by the unit (``"12.39 mm"``)."""
    text = format_number(value, signed=signed, unit=unit)
    return f"{text} {unit}" if unit and value is not None else text


def format_duration(seconds: float | None) -> str:
    """``"12.3 s"``, ``"4 min 05 s"``, ``"2 h 03 min"``; ``-`` for None."""
    if seconds is None or not math.isfinite(seconds):
        return "-"
    if seconds < 60:
        return f"{seconds:.3g} s" if seconds < 10 else f"{seconds:.1f} s"
    whole = round(seconds)
    if whole < 3600:
        return f"{whole // 60} min {whole % 60:02d} s"
    return f"{whole // 3600} h {whole % 3600 // 60:02d} min"


def margin(m: Measurement) -> float | None:
    """How far the value lies inside its limit (measurement unit): the distance to the nearer
    bound, positive inside, negative outside; None without a limit."""
    if m.limit is None:
        return None
    gaps = []
    if m.limit.high is not None:
        gaps.append(m.limit.high - m.value)
    if m.limit.low is not None:
        gaps.append(m.value - m.limit.low)
    return min(gaps) if gaps else None


@functools.lru_cache(maxsize=1)
def jinja_environment() -> jinja2.Environment:
    """The templates' environment: every ``{{ }}`` is HTML-escaped (record text can never become
    markup), an undefined name is an error rather than an empty string."""
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(_TEMPLATES),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )
    env.filters["num"] = format_number
    env.filters["signed"] = functools.partial(format_number, signed=True)
    env.filters["duration"] = format_duration
    env.globals["CSP"] = CSP
    env.globals["VERDICT_MARKS"] = VERDICT_MARKS
    env.globals["OUTCOME_MARKS"] = OUTCOME_MARKS
    env.globals["RESULT_MARKS"] = RESULT_MARKS
    return env
