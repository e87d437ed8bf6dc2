"""Comparing two run records as ``scripts/same_figures.py`` does, and further: every suite's
trials (index, parameters, samples, measurements, status, error, duration) and suite-level
measurements, run id and timestamps (``created``, ``started_s``, ``ended_s``) and wall-clock times
(``wall_s``: how long the machine took, never the same twice) aside."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

TIMES = {"started_s", "ended_s", "wall_s"}


def load(directory: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((directory / "results.json").read_text(encoding="utf-8"))
    return data


def _walk(a: object, b: object, where: str, tol: float, out: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for key in sorted(a.keys() | b.keys()):
            if key in TIMES:
                continue
            if key not in a or key not in b:
                out.append(f"{where}.{key}: only in {'A' if key in a else 'B'}")
                continue
            _walk(a[key], b[key], f"{where}.{key}", tol, out)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{where}: {len(a)} vs {len(b)} items")
            return
        for k, (x, y) in enumerate(zip(a, b, strict=True)):
            _walk(x, y, f"{where}[{k}]", tol, out)
    elif (isinstance(a, float) and isinstance(b, float)
          and not (isinstance(a, bool) or isinstance(b, bool))):
        if not (a == b or abs(a - b) <= tol * max(1.0, abs(a), abs(b))
                or (math.isnan(a) and math.isnan(b))):
            out.append(f"{where}: {a!r} vs {b!r}")
    elif a != b or type(a) is not type(b):
        out.append(f"{where}: {a!r} vs {b!r}")


def record_differences(a: Path, b: Path, *, tol: float = 0.0,
                       environment: bool = True) -> list[str]:
    """What differs between the records in run directories ``a`` and ``b`` (empty: the same
    record); floats equal to ``tol`` (relative, or absolute below 1); ``environment=False``
    leaves the environment (the limits file's path) out."""
    ra, rb = load(a), load(b)
    out: list[str] = []
    _walk(ra["suites"], rb["suites"], "suites", tol, out)
    for key in ("planned_suites", "environment") if environment else ("planned_suites",):
        _walk(ra[key], rb[key], key, tol, out)
    return out
