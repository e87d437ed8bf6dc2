"""Several arms in one run: ``armbench run --port P1 --port P2 ...`` runs the suites on every arm
at once, one :func:`~armbench.bench.runner.execute.execute` per arm on one event loop.

Each arm is a run of its own in ``RUN_DIR/<arm>/`` (its record, capture and reports, exactly as a
single-port run lays them out; its name is its unit under test's, so ``--dut`` is refused);
``RUN_DIR/fleet.json`` lists the arms, their ports, verdicts and exit statuses (what the fleet
page reads). An arm is named by ``--port NAME=PORT``, else by its
port: the place of a ``labgrid://PLACE``, the port with everything but letters, digits, ``.``,
``_`` and ``-`` turned into ``-`` otherwise (``/dev/ttyUSB0`` → ``dev-ttyUSB0``).

Every arm's plan is prepared (checked), and every arm that is already there must answer at its
port (:mod:`~armbench.bench.runner.probe`), before any arm moves or the fleet's folder is made:
a port where no arm answers refuses the fleet as bad input. Once begun, one arm failing (a lost
port, a limit, a bug) does not stop the others; the fleet's exit status is the worst of the
arms' (:func:`fleet_exit_status`) and :attr:`FleetOutcome.failed` names the arms that did not pass.
The loop is the virtual-time one when every arm is ``fake://``, a real one otherwise (a
``fake://`` arm beside real ones then runs on real time).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, cast

from armbench.bench.runner.execute import execute
from armbench.bench.runner.lock import hold_run_folder
from armbench.bench.runner.options import (
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    EXIT_PASS,
    BenchPlan,
    EmulatorFactory,
    RunOptions,
    RunOutcome,
)
from armbench.bench.runner.plan import prepare
from armbench.bench.runner.probe import probe_arms_sync
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import SettingsError
from armbench.drivers.transports.target import target_of
from armbench.record import RESULTS_FILE, load_record, new_run_id
from armbench.record.files import make_directory
from armbench.record.fleet_index import (
    FLEET_FILE,
    FleetArm,
    FleetIndex,
    read_fleet_index,
    write_fleet_index,
)
from armbench.record.verdict import worst_exit_status

__all__ = ["FLEET_FILE", "Arm", "FleetOutcome", "arm_name", "fleet_exit_status", "parse_arms",
           "run_fleet_sync"]

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")


@dataclass(frozen=True, slots=True)
class Arm:
    """One arm of the fleet: its name (its folder in the run directory) and its port."""

    name: str
    port: str


def arm_name(port: str) -> str:
    """The name of the arm on ``port``: what its target makes of it (a labgrid place's name, the
    address after the scheme), sanitised."""
    text = target_of(port).name()
    name = re.sub(r"[^A-Za-z0-9._]+", "-", text).strip("-.")
    return name[:64] or "arm"


def parse_arms(ports: Sequence[str]) -> list[Arm]:
    """The arms of ``--port`` values, each ``PORT`` or ``NAME=PORT``; a name or a port given
    twice is refused."""
    arms: list[Arm] = []
    for given in ports:
        head, sep, tail = given.partition("=")
        if sep and "://" not in head and "/" not in head and "?" not in head:
            if not _NAME.fullmatch(head):
                raise ArmbenchError(f"--port {given!r}: the arm name {head!r} must be letters, "
                                    "digits, '.', '_' or '-' (at most 64)")
            if not tail:
                raise ArmbenchError(f"--port {given!r}: no port after the arm name {head!r}")
            arms.append(Arm(head, tail))
        else:
            arms.append(Arm(arm_name(given), given))
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


def fleet_exit_status(statuses: Sequence[int]) -> int:
    """The fleet's exit status: the worst arm's (:func:`armbench.record.verdict.worst_exit_status`:
    130, then 2, 4, 1, 3, 0)."""
    return worst_exit_status(statuses)


@dataclass(slots=True)
class FleetOutcome:
    """What a fleet run left: its directory, each arm's outcome (in ``--port`` order; None for
    an arm that has no record: it failed before its run began) and the fleet's exit status."""

    out_dir: Path
    arms: list[Arm]
    outcomes: list[RunOutcome | None]
    errors: list[str | None]
    exit_status: int

    @property
    def failed(self) -> list[str]:
        """Names of the arms that did not pass."""
        return [a.name for a, s in zip(self.arms, self.statuses, strict=True) if s != EXIT_PASS]

    @property
    def statuses(self) -> list[int]:
        """Each arm's exit status."""
        return [EXIT_ERROR if o is None else o.exit_status for o in self.outcomes]


def _arm_options(options: RunOptions, arm: Arm, out_dir: Path) -> RunOptions:
    """The options of one arm: its port, its folder, its own baseline in the baseline fleet, its
    name as its unit's name (``--dut``: one arm's)."""
    return dataclasses.replace(options, port=arm.port, out=out_dir / arm.name,
                               baseline=_own_baseline(options, arm), resume=None, dut=arm.name)


def _own_baseline(options: RunOptions, arm: Arm) -> Path | None:
    """The arm's record in the baseline fleet run (``--baseline DIR``)."""
    if options.baseline is None:
        return None
    own = Path(options.baseline) / arm.name / RESULTS_FILE
    if not own.is_file():
        raise ArmbenchError(f"--baseline {options.baseline}: a fleet's baseline is an earlier "
                            f"fleet run holding the same arms; {own} does not exist")
    return own


def _resumed_options(options: RunOptions, arm: Arm, out_dir: Path) -> RunOptions:
    """The options of one arm of a fleet being resumed: its own record continued."""
    folder = out_dir / arm.name
    if not (folder / RESULTS_FILE).exists():
        raise ArmbenchError(f"--resume {out_dir}: arm {arm.name!r} has no record "
                            f"({folder / RESULTS_FILE}); start a new fleet run")
    return dataclasses.replace(options, port=arm.port, resume=folder, out=None,
                               baseline=_own_baseline(options, arm))


def _write_index(out_dir: Path, fleet_id: str, arms: Sequence[Arm],
                 outcomes: Sequence[RunOutcome | None], errors: Sequence[str | None],
                 status: int | None) -> None:
    write_fleet_index(out_dir, FleetIndex(fleet_id, tuple(
        FleetArm(a.name, a.port, None if o is None else o.verdict,
                 None if o is None else o.exit_status, e)
        for a, o, e in zip(arms, outcomes, errors, strict=True)), status))


class _Prefixed:
    """A progress stream that starts every line with the arm's name (never a terminal: the
    lines of several arms interleave, none is rewritten in place)."""

    def __init__(self, stream: IO[str], name: str) -> None:
        self.stream = stream
        self.prefix = f"{name}: "
        self._at_line_start = True

    def write(self, text: str) -> int:
        out = []
        for piece in text.splitlines(keepends=True):
            if self._at_line_start:
                out.append(self.prefix)
            out.append(piece)
            self._at_line_start = piece.endswith("\n")
        self.stream.write("".join(out))
        return len(text)

    def flush(self) -> None:
        self.stream.flush()

    @staticmethod
    def isatty() -> bool:
        return False


def _from_disk(plan: BenchPlan, status: int, error: str) -> RunOutcome | None:
    """The outcome of an arm whose run ended on an exception: its record as on disk."""
    path = plan.out_dir / RESULTS_FILE
    if not path.exists():
        return None
    return RunOutcome(plan.out_dir, load_record(path), status, interrupted=status ==
                      EXIT_INTERRUPTED, error=error, warnings=tuple(plan.warnings),
                      capture_max_bytes=plan.capture_max_bytes)


async def _run_arm(plan: BenchPlan, progress: IO[str] | None,
                   emulator_factory: EmulatorFactory | None) -> tuple[RunOutcome | None,
                                                                      str | None]:
    """One arm's run; an exception that escapes it ends this arm only."""
    try:
        outcome = await execute(plan, progress=progress, emulator_factory=emulator_factory)
    except Exception as exc:  # the other arms go on: this one is in error
        error = f"{type(exc).__name__}: {exc}"
        return _from_disk(plan, EXIT_ERROR, error), error
    return outcome, outcome.error


async def _run_all(plans: Sequence[BenchPlan], arms: Sequence[Arm], progress: IO[str] | None,
                   emulator_factory: EmulatorFactory | None
                   ) -> list[tuple[RunOutcome | None, str | None]]:
    return list(await asyncio.gather(*(
        _run_arm(plan, None if progress is None else cast(IO[str], _Prefixed(progress,
                                                                             arm.name)),
                 emulator_factory)
        for plan, arm in zip(plans, arms, strict=True))))


def run_fleet_sync(options: RunOptions, ports: Sequence[str], *,
                   progress: IO[str] | None = sys.stderr,
                   emulator_factory: EmulatorFactory | None = None) -> FleetOutcome:
    """Check every arm's plan, then run them all at once on one loop (see the module
    docstring); with ``options.resume`` (a fleet's run directory, no ``ports``) continue every
    arm of that fleet. Ctrl-C returns each arm's record on disk with exit status 130. The
    fleet's folder is locked while the fleet writes it (each arm's folder too, by the runner):
    a second writer is refused before it reads or writes anything."""
    with contextlib.ExitStack() as held:
        if options.resume is not None and (Path(options.resume) / FLEET_FILE).is_file():
            held.enter_context(hold_run_folder(options.resume))
        return _run_fleet(options, ports, progress, emulator_factory, held)


def _run_fleet(options: RunOptions, ports: Sequence[str], progress: IO[str] | None,
               emulator_factory: EmulatorFactory | None,
               held: contextlib.ExitStack) -> FleetOutcome:
    if options.resume is not None:
        out_dir = Path(options.resume)
        if ports:
            raise ArmbenchError("--resume: a fleet continues on the ports it began with; "
                                "leave --port out")
        index = read_fleet_index(out_dir)
        fleet_id = index.fleet_id
        arms = [Arm(a.name, a.port) for a in index.arms]
        plans = [prepare(_resumed_options(options, arm, out_dir)) for arm in arms]
    else:
        if options.dut is not None:
            raise ArmbenchError("--dut names one unit; a fleet's arms are named by --port "
                                "NAME=PORT, each name its unit's")
        arms = parse_arms(ports)
        fleet_id = new_run_id()
        out_dir = (Path(options.out) if options.out is not None
                   else Path(options.runs_root) / fleet_id)
        if (out_dir / FLEET_FILE).exists():
            raise ArmbenchError(f"--out {out_dir}: already holds a fleet run; resume it "
                                "(--resume) or choose another --out")
        plans = [prepare(_arm_options(options, arm, out_dir)) for arm in arms]
        if len(plans) > 1 and plans[0].dut.serial is not None:
            raise SettingsError("dut.serial", plans[0].dut.serial,
                                f"is one arm's serial number, not each of {len(plans)} arms'")
    for plan, arm in zip(plans, arms, strict=True):
        if plan.resume is None:
            plan.run_id = f"{fleet_id}-{arm.name}"
    probe_arms_sync(plans)  # every arm answers before the fleet's folder is made
    make_directory(out_dir, "--out" if options.out is not None else "run folder")
    held.enter_context(hold_run_folder(out_dir))
    _write_index(out_dir, fleet_id, arms, [None] * len(arms), [None] * len(arms), None)
    main = _run_all(plans, arms, progress, emulator_factory)
    try:
        if all(plan.target.virtual for plan in plans):
            from armbench.fakes.clock.vclock import run_virtual

            results = run_virtual(main)
        else:
            results = asyncio.run(main)
    except (KeyboardInterrupt, asyncio.CancelledError):
        results = [(_from_disk(plan, EXIT_INTERRUPTED, "interrupted"), "interrupted")
                   for plan in plans]
    outcomes = [o for o, _ in results]
    errors = [e for _, e in results]
    statuses = [EXIT_ERROR if o is None else o.exit_status for o in outcomes]
    if any(e == "interrupted" for e in errors):
        statuses.append(EXIT_INTERRUPTED)
    status = fleet_exit_status(statuses)
    _write_index(out_dir, fleet_id, arms, outcomes, errors, status)
    return FleetOutcome(out_dir, arms, outcomes, errors, status)

