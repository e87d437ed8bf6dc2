"""The figures of a script's measuring child: ``PYTHON SCRIPT --child OUT_DIR OPTIONS...`` run in
a fresh process (the armbench of ``PYTHON``'s environment), its last line of output the figures
as one JSON value. Shared by the figure scripts that measure ``armbench run`` in a process of its
own (``trial_cpu.py``, ``emulator_share.py``)."""

from __future__ import annotations

import json
import subprocess
import tempfile
from pathlib import Path
from typing import Any

__all__ = ["child_figures"]


def child_figures(python: str, script: str, options: list[str], timeout_s: float) -> Any:
    """The JSON value the child of ``script`` printed last, its run directory a temporary one;
    :class:`SystemExit` naming the child when it could not start, failed or printed none. Exit
    status 1 is a run whose verdict failed: its trials still ran, its figures count."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            done = subprocess.run([python, script, "--child", str(Path(tmp) / "run"), *options],
                                  capture_output=True, text=True, timeout=timeout_s)
        except OSError as exc:  # no such interpreter, or not one that runs
            raise SystemExit(f"{Path(script).name}: cannot run {python!r}: {exc}") from exc
    lines = done.stdout.strip().splitlines()
    if done.returncode not in (0, 1) or not lines or not lines[-1].startswith("{"):
        raise SystemExit(f"{Path(script).name} with {python} {options} failed "
                         f"({done.returncode}): {done.stderr[-800:]}")
    return json.loads(lines[-1])
