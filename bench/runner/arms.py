"""The arms of a run and where each one writes: what :func:`lay_out` makes of the options.

``--port [NAME=]PORT`` given once (or not at all: ``fake://``) is a run of one arm, laid out as a
run folder (``OUT/results.json``, ``OUT/report.html``, ...); given several times, a fleet, laid out
as ``OUT/fleet.json`` and a folder per arm (``OUT/<arm>/``), each laid out as a run of one arm. A
``--resume`` continues the arms of the folder it names. Everything of an arm that is its own (its
port, folder, run id, baseline, the record it continues, its unit's name) is an :class:`ArmRun`,
which :func:`~armbench.bench.runner.plan.prepare` reads beside the options every arm shares: the
runner prepares and runs every arm the same way (:mod:`~armbench.bench.runner.fleet_run`).

An arm of a fleet is named by ``NAME=``, else by its port as its target names it
(:func:`arm_name`: a labgrid place's name, the address after the scheme, sanitised); its name is
its folder, its run id's suffix and its unit under test's name (``--dut`` is refused), and its
baseline is its own record in the baseline fleet (``--baseline DIR/<arm>/results.json``).
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from armbench.bench.runner.options import RunOptions
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.transports.target import target_of
from armbench.record import RESULTS_FILE, new_run_id
from armbench.record.fleet_index import FLEET_FILE, is_fleet, read_fleet_index

__all__ = ["Arm", "ArmRun", "RunLayout", "arm_name", "lay_out", "parse_arms"]

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


@dataclass(frozen=True, slots=True)
class Arm:
    """One arm of a fleet: its name (its folder in the run directory) and its port."""

    name: str
    port: str


@dataclass(frozen=True, slots=True)
class ArmRun:
    """What one arm of a run has of its own; the rest of its run is the options'."""

    name: str | None
    """Its name in a fleet (its folder there); None for the one arm of a run."""
    port: str | None
    """Its port; None: the port of the record it continues, else ``fake://``."""
    out: Path
    """Its run folder."""
    run_id: str | None
    """The id of its new record; None when it continues one."""
    resume: Path | None
    """The run folder whose record it continues, or None."""
    baseline: Path | None
    """The record it is compared with, or None."""
    dut: str | None
    """Its unit under test's name over the config's ``[dut] name`` (``--dut``; in a fleet, its
    name)."""


@dataclass(frozen=True, slots=True)
class RunLayout:
    """The arms of a run and the folder it writes: a run folder (one arm), or a fleet's."""

    out_dir: Path
    out_flag: str
    """How messages name :attr:`out_dir`: ``--out``, or ``run folder`` when it is a default."""
    fleet_id: str | None
    """The fleet's id; None: one arm, laid out as a run of its own (no ``fleet.json``)."""
    arms: tuple[ArmRun, ...]

    @property
    def fleet(self) -> bool:
        """Whether the folder is a fleet's (``fleet.json``, a folder per arm)."""
        return self.fleet_id is not None

    def only(self) -> ArmRun:
        """The one arm of a run that is not a fleet."""
        if self.fleet:
            raise ArmbenchError(f"--port: {len(self.arms)} arms, not one; each is prepared on "
                                "its own (lay_out(options).arms)")
        return self.arms[0]


def arm_name(port: str) -> str:
    """The name of the arm on ``port``: what its target makes of it (a labgrid place's name, the
    address after the scheme), sanitised."""
    text = target_of(port).name()
    name = re.sub(r"[^A-Za-z0-9._]+", "-", text).strip("-.")
    return name[:64] or "arm"


def _split(given: str) -> tuple[str | None, str]:
    """``NAME=PORT`` → its name (checked) and port; ``PORT`` → None and the port."""
    head, sep, tail = given.partition("=")
    if not sep or "://" in head or "/" in head or "?" in head:
        return None, given
    if not _NAME.fullmatch(head):
        raise ArmbenchError(f"--port {given!r}: the arm name {head!r} must be letters, digits, "
                            "'.', '_' or '-' (at most 64)")
    if not tail:
        raise ArmbenchError(f"--port {given!r}: no port after the arm name {head!r}")
    return head, tail


def parse_arms(ports: Sequence[str]) -> list[Arm]:
    """The arms of ``--port`` values, each ``PORT`` or ``NAME=PORT``, named; a name or a port
    given twice is refused."""
    arms = [Arm(name or arm_name(port), port) for name, port in map(_split, ports)]
    names: dict[str, str] = {}
    ports_seen: dict[str, str] = {}
    for arm in arms:
        if arm.name in names:
            raise ArmbenchError(f"--port: the arms on {names[arm.name]!r} and {arm.port!r} are "
                                f"both named {arm.name!r}; name them with --port NAME=PORT")
        if arm.port in ports_seen:
            raise ArmbenchError(f"--port: {arm.port!r} is given twice (arms "
                                f"{ports_seen[arm.port]!r} and {arm.name!r})")
        names[arm.name] = arm.port
        ports_seen[arm.port] = arm.name
    return arms


def _own_baseline(options: RunOptions, name: str) -> Path | None:
    """The arm's record in the baseline fleet run (``--baseline DIR``)."""
    if options.baseline is None:
        return None
    own = Path(options.baseline) / name / RESULTS_FILE
    if not own.is_file():
        raise ArmbenchError(f"--baseline {options.baseline}: a fleet's baseline is an earlier "
                            f"fleet run holding the same arms; {own} does not exist")
    return own


def _resumed(options: RunOptions, folder: Path) -> RunLayout:
    """The arms of the run in ``folder``, each continuing its record (a fleet's on the ports it
    began with; a run of one arm on its recorded port, or on ``--port``)."""
    if options.out is not None and Path(options.out).resolve() != folder.resolve():
        raise ArmbenchError("--out: a resumed run continues in its own directory "
                            f"({folder}); leave --out out")
    baseline = None if options.baseline is None else Path(options.baseline)
    if not is_fleet(folder):
        if len(options.ports) > 1:
            raise ArmbenchError(f"--resume: {folder} is the run of one arm; give one --port at "
                                "most")
        port = _split(options.ports[0])[1] if options.ports else None
        return RunLayout(folder, "--resume", None,
                         (ArmRun(None, port, folder, None, folder, baseline, None),))
    if options.ports:
        raise ArmbenchError("--resume: a fleet continues on the ports it began with; "
                            "leave --port out")
    index = read_fleet_index(folder)
    arms = []
    for arm in index.arms:
        own = folder / arm.name
        if not (own / RESULTS_FILE).exists():
            raise ArmbenchError(f"--resume {folder}: arm {arm.name!r} has no record "
                                f"({own / RESULTS_FILE}); start a new fleet run")
        arms.append(ArmRun(arm.name, arm.port, own, None, own, _own_baseline(options, arm.name),
                           None))
    return RunLayout(folder, "--resume", index.fleet_id, tuple(arms))


def _check_text_inputs(options: RunOptions) -> None:
    """Every path and string the record stores must be text (UTF-8): a file name of other bytes
    (``b'\\xff.toml'`` on POSIX) is refused naming it, before anything is read or made."""
    given = (("--config", options.config), ("--settings", options.settings),
             ("--faults", options.faults), ("--out", options.out),
             ("--baseline", options.baseline), ("--resume", options.resume),
             *(("--port", port) for port in options.ports),
             ("--tracker", options.tracker), ("--dut", options.dut),
             *(("--meta", meta) for meta in options.meta),
             ("runs folder", options.runs_root),
             *(("SUITE", suite) for suite in options.suites))
    for flag, value in given:
        if value is None:
            continue
        text = os.fspath(value)
        try:
            text.encode("utf-8")
        except UnicodeEncodeError:
            shown = os.fsencode(text).decode("utf-8", "backslashreplace")
            raise ArmbenchError(f"{flag}: {shown} is not valid UTF-8 text (a file name of "
                                "other bytes cannot be kept in the record); rename it") from None



def lay_out(options: RunOptions) -> RunLayout:
    """The arms ``options`` name and where each writes (see the module docstring); a name, a
    port or a folder that cannot be is refused (:class:`ArmbenchError`), nothing is made."""
    _check_text_inputs(options)
    if options.overwrite and (options.out is None or options.resume is not None):
        raise ArmbenchError("--overwrite replaces the run in --out: give --out (and no --resume)")
    if options.resume is not None:
        return _resumed(options, Path(options.resume))
    run_id = new_run_id()
    out_dir = Path(options.out) if options.out is not None else Path(options.runs_root) / run_id
    flag = "--out" if options.out is not None else "run folder"
    if (out_dir / FLEET_FILE).exists() and not options.overwrite:
        raise ArmbenchError(f"--out {out_dir}: already holds a fleet run; resume it (--resume), "
                            "replace it (--overwrite) or choose another --out")
    if len(options.ports) <= 1:  # one arm, the run folder its own: it needs no name
        port = _split(options.ports[0])[1] if options.ports else "fake://"
        baseline = None if options.baseline is None else Path(options.baseline)
        return RunLayout(out_dir, flag, None,
                         (ArmRun(None, port, out_dir, run_id, None, baseline, options.dut),))
    if options.dut is not None:
        raise ArmbenchError("--dut names one unit; a fleet's arms are named by --port "
                            "NAME=PORT, each name its unit's")
    return RunLayout(out_dir, flag, run_id, tuple(
        ArmRun(arm.name, arm.port, out_dir / arm.name, f"{run_id}-{arm.name}", None,
               _own_baseline(options, arm.name), arm.name)
        for arm in parse_arms(options.ports)))
