"""Do two run records hold the same figures? Every measurement, suite-level and per trial, is
compared by name: same set of names, values equal to ``--tol`` (default 1e-12, absolute or relative
to the larger value, whichever is looser), same unit and outcome. Used to check that a change meant
to keep behaviour (a refactoring) gives the same ``results.json`` (exit 0) or not (exit 1).

    python scripts/same_figures.py RUN_A/results.json RUN_B/results.json [--tol 1e-12]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

Figure = tuple[float | None, str, str]


def _load(path: str) -> dict[str, Any]:
    p = Path(path)
    if p.is_dir():
        p = p / "results.json"
    record: dict[str, Any] = json.loads(p.read_text(encoding="utf-8"))
    return record


def figures(record: dict[str, Any]) -> Iterator[tuple[str, Figure]]:
    """``(where, (value, unit, outcome))`` of every measurement in the record."""
    for name, suite in sorted(record["suites"].items()):
        for m in suite.get("measurements", []):
            yield f"{name}/{m['name']}", (m["value"], m["unit"], m["outcome"])
        for trial in suite.get("trials", []):
            for m in trial.get("measurements", []):
                yield (f"{name}/trial {trial['index']}/{m['name']}",
                       (m["value"], m["unit"], m["outcome"]))


def _close(a: float | None, b: float | None, tol: float) -> bool:
    if a is None or b is None:
        return a is b
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs(a - b) <= tol * max(1.0, abs(a), abs(b))


def differences(a: dict[str, Any], b: dict[str, Any], tol: float) -> list[str]:
    """One line per figure that is missing on a side or differs."""
    fa, fb = dict(figures(a)), dict(figures(b))
    out = [f"only in A: {k}" for k in sorted(fa.keys() - fb.keys())]
    out += [f"only in B: {k}" for k in sorted(fb.keys() - fa.keys())]
    for key in sorted(fa.keys() & fb.keys()):
        (va, ua, oa), (vb, ub, ob) = fa[key], fb[key]
        if not _close(va, vb, tol) or ua != ub or oa != ob:
            out.append(f"differs: {key}: {va} {ua} {oa} vs {vb} {ub} {ob}")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("a")
    parser.add_argument("b")
    parser.add_argument("--tol", type=float, default=1e-12)
    args = parser.parse_args(argv)
    a, b = _load(args.a), _load(args.b)
    diff = differences(a, b, args.tol)
    count = len(dict(figures(a)))
    for line in diff:
        print(line)
    print(f"{count} figures in A, {len(diff)} differences (tolerance {args.tol:g})")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main())
