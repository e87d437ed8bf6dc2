"""Power switches: how the bench cuts and restores the arm's power (start-up recovery tests).

Four implementations of :class:`~armbench.bench.suites.base.PowerSwitch`:

- :class:`EmulatorPower` — ``fake://``: the emulator's own power control (instantaneous, on the
  loop's clock, so on virtual time);
- :class:`HarnessPower` — ``avr://``: the firmware harness's control channel (``power off``,
  ``power on``), in real time;
- :class:`CommandPower` — hardware with a relay: runs a configured command for "off" and one for
  "on" (``--power-command "relay off" "relay on"``), each with a timeout; a non-zero exit status,
  a timeout or a missing program raise :class:`PowerError`. A ``labgrid://`` place with a power
  resource names its own commands (labgrid's client switching it, :func:`place_power`);
- :class:`ManualPower` — hardware without a relay: prints a prompt for the operator and waits
  for Enter (``--power-manual``).

The two ports' own switches (:func:`port_power` finds them) can also re-reference an arm whose
start-up recovery stalled (:class:`~armbench.bench.suites.base.ReReferencing`), as a lab does by
hand; a relay or an operator prompt cannot. All waiting is asyncio (a subprocess, or a line read
in the default executor), so a suite awaiting a power switch can be cancelled like any other step.
See ``docs/runner.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import shlex
import shutil
import sys
from collections.abc import Callable, Sequence
from typing import IO, Any, Protocol, runtime_checkable

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.transports.base import EmulatedTarget

__all__ = [
    "DEFAULT_COMMAND_TIMEOUT_S",
    "CommandPower",
    "EmulatorPower",
    "HarnessPower",
    "ManualPower",
    "PowerError",
    "parse_command",
    "place_power",
    "port_power",
]

#: How long a power command may run before it is killed and the switch fails (s).
DEFAULT_COMMAND_TIMEOUT_S = 10.0
#: How long a place's power command may run (s): labgrid's client starts a Python and a gRPC
#: session for each switch.
PLACE_POWER_TIMEOUT_S = 60.0
#: How much of a failing command's output the error message quotes (characters).
_OUTPUT_TAIL = 400


class PowerError(ArmbenchError, RuntimeError):
    """The power could not be switched: a command failed, timed out or is missing; the operator's
    input closed; no emulator behind the port."""


@runtime_checkable
class _EmulatorLike(Protocol):
    def power_off(self) -> None: ...

    def power_on(self) -> None: ...


class EmulatorPower:
    """The power control of the ``fake://`` emulator.

    ``source`` is the :class:`~armbench.fakes.firmware.arm_emulator.ArmEmulator` itself, or an
    :class:`~armbench.drivers.transports.base.EmulatedTarget` (an
    :class:`~armbench.drivers.host.arm.Arm` or a fake transport) whose emulator is read at each
    switch, so the switch follows the arm to a new emulator after a reconnection.
    """

    def __init__(self, source: Any) -> None:
        self._source = source

    @property
    def emulator(self) -> _EmulatorLike:
        """The emulator switched now; :class:`PowerError` if there is none."""
        src = self._source
        if isinstance(src, _EmulatorLike):
            return src
        inner = src.emulator if isinstance(src, EmulatedTarget) else None
        if not isinstance(inner, _EmulatorLike):
            raise PowerError(f"{src!r} has no emulator to switch (EmulatorPower is for fake://)")
        return inner

    async def power_off(self) -> None:
        """Cut the emulator's power now (loop time)."""
        self.emulator.power_off()
        await asyncio.sleep(0)

    async def power_on(self) -> None:
        """Restore the emulator's power now (loop time); its boards boot."""
        self.emulator.power_on()
        await asyncio.sleep(0)

    async def re_reference(self) -> None:
        """While the power is off: blank the EEPROMs; the emulator's firmware then takes each
        motor's position as its counter, what an operator re-referencing the joints achieves."""
        for eeprom in getattr(self.emulator, "eeproms", ()):
            eeprom.erase()
        await asyncio.sleep(0)

    def __repr__(self) -> str:
        return "EmulatorPower()"


class _HarnessLike(Protocol):
    async def power(self, on: bool) -> None: ...

    async def re_reference(self) -> None: ...


def _harness_of(source: Any) -> _HarnessLike | None:
    """The firmware harness ``source`` is or holds (an ``avr://`` transport's ``harness``, an
    arm's current transport's), else None."""
    if callable(getattr(source, "re_reference", None)) and callable(getattr(source, "power",
                                                                            None)):
        found: _HarnessLike = source
        return found
    for holder in (source, getattr(source, "transport", None)):
        harness = getattr(holder, "harness", None)
        if harness is not None:
            return _harness_of(harness)
    return None


class HarnessPower:
    """The power control of the firmware harness behind an ``avr://`` port, through its control
    channel: all four boards cut and restored (EEPROM and motor positions survive), and a
    stalled arm re-referenced (:meth:`re_reference`).

    ``source`` is the :class:`~armbench.fakes.avr.harness.Harness`, an ``avr://`` transport or an
    arm on
    one, resolved at each switch (the arm's transport is a new one after a reconnection).
    """

    def __init__(self, source: Any) -> None:
        self._source = source

    @property
    def harness(self) -> _HarnessLike:
        """The harness switched now; :class:`PowerError` if there is none."""
        try:
            harness = _harness_of(self._source)
        except ArmbenchError as exc:  # the arm is closed
            raise PowerError(f"no harness to switch: {exc}") from exc
        if harness is None:
            raise PowerError(f"{self._source!r} has no firmware harness to switch "
                             "(HarnessPower is for avr://)")
        return harness

    async def power_off(self) -> None:
        """Cut the four boards' power (the harness takes it at its next simulated millisecond)."""
        await self.harness.power(False)

    async def power_on(self) -> None:
        """Restore the power; the boards boot."""
        await self.harness.power(True)

    async def re_reference(self) -> None:
        """While the power is off: every joint back to its zero position, every EEPROM blanked,
        as a lab re-homes the arm by hand and erases the EEPROMs with a programmer; at power-up
        the firmware counts from zero where the joints stand."""
        await self.harness.re_reference()

    def __repr__(self) -> str:
        return "HarnessPower()"


def port_power(source: Any) -> EmulatorPower | HarnessPower | CommandPower | None:
    """The power switch the port behind ``source`` (an arm, a transport, an emulator) has of its
    own: the emulator's on ``fake://``, the firmware harness's on ``avr://``, the place's power
    resource on ``labgrid://`` (the commands its transport names, :func:`place_power`); None
    for other hardware, whose power needs a relay command or the operator."""
    if (callable(getattr(source, "power_off", None))
            or (isinstance(source, EmulatedTarget) and source.emulator is not None)):
        return EmulatorPower(source)
    try:
        harness = _harness_of(source)
    except ArmbenchError:
        return None
    return HarnessPower(source) if harness is not None else place_power(source)


def place_power(source: Any) -> CommandPower | None:
    """The power switch of a lab's place behind ``source`` (an arm or its transport): a
    transport that can switch its arm's power names the commands (``power_commands()``:
    ``labgrid://`` with a power resource); None where none does."""
    holders = [source]
    with contextlib.suppress(AttributeError, ArmbenchError):  # no transport, or a closed arm
        holders.append(source.transport)
    for holder in holders:
        commands = getattr(holder, "power_commands", None)
        found = commands() if callable(commands) else None
        if found is not None:
            off, on = found
            return CommandPower(off, on, timeout_s=PLACE_POWER_TIMEOUT_S)
    return None


def parse_command(command: str | Sequence[str], what: str) -> list[str]:
    """A command line as an argument list: a string is split like a POSIX shell would
    (``shlex.split``; no shell runs, so no pipes or redirections), a sequence is taken as is.
    Raises :class:`PowerError` naming ``what`` for an empty command or an unbalanced quote."""
    if isinstance(command, str):
        try:
            argv = shlex.split(command)
        except ValueError as exc:
            raise PowerError(f"{what}: {command!r} cannot be parsed: {exc}") from None
    else:
        argv = [str(a) for a in command]
    if not argv or not argv[0]:
        raise PowerError(f"{what}: the command is empty")
    return argv


class CommandPower:
    """Switches the power by running a command: ``off_cmd`` to cut, ``on_cmd`` to restore.

    Each command is a string (split like a shell would, but run without a shell) or an argument
    list. It runs with ``asyncio.create_subprocess_exec``; the switch is done when the command
    exits with status 0 within ``timeout_s``. A non-zero status raises :class:`PowerError` with
    the status and the end of the command's output; a command still running after ``timeout_s``
    is killed and raises too. :meth:`check` (called by the runner before anything moves) verifies
    that both programs exist.
    """

    def __init__(self, off_cmd: str | Sequence[str], on_cmd: str | Sequence[str], *,
                 timeout_s: float = DEFAULT_COMMAND_TIMEOUT_S) -> None:
        self.off_argv = parse_command(off_cmd, "power off command")
        self.on_argv = parse_command(on_cmd, "power on command")
        if not (isinstance(timeout_s, (int, float)) and timeout_s > 0):
            raise PowerError(f"power command timeout: {timeout_s!r} must be a number > 0")
        self.timeout_s = float(timeout_s)

    def check(self) -> None:
        """Raise :class:`PowerError` if a command's program cannot be found."""
        for what, argv in (("power off command", self.off_argv),
                           ("power on command", self.on_argv)):
            if shutil.which(argv[0]) is None:
                raise PowerError(f"{what}: program {argv[0]!r} not found (not on PATH, or not "
                                 "executable)")

    async def power_off(self) -> None:
        """Run the "off" command; return when it succeeded."""
        await self._run(self.off_argv, "power off")

    async def power_on(self) -> None:
        """Run the "on" command; return when it succeeded."""
        await self._run(self.on_argv, "power on")

    async def _run(self, argv: list[str], what: str) -> None:
        shown = shlex.join(argv)
        try:
            proc = await asyncio.create_subprocess_exec(
                *argv, stdin=asyncio.subprocess.DEVNULL, stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.STDOUT)
        except OSError as exc:
            raise PowerError(f"{what}: {shown!r} could not be started: "
                             f"{exc.strerror or exc}") from exc
        try:
            output, _ = await asyncio.wait_for(proc.communicate(), self.timeout_s)
        except TimeoutError:
            await _kill(proc)
            raise PowerError(f"{what}: {shown!r} did not finish within {self.timeout_s:g} s "
                             "(killed)") from None
        except BaseException:  # cancelled: do not leave the command running
            await _kill(proc)
            raise
        if proc.returncode != 0:
            text = output.decode("utf-8", "replace").strip()
            tail = text[-_OUTPUT_TAIL:] if text else "no output"
            raise PowerError(f"{what}: {shown!r} exited with status {proc.returncode}: {tail}")

    def __repr__(self) -> str:
        return f"CommandPower(off={shlex.join(self.off_argv)!r}, on={shlex.join(self.on_argv)!r})"


async def _kill(proc: asyncio.subprocess.Process) -> None:
    if proc.returncode is None:
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
        with contextlib.suppress(Exception):
            await proc.wait()


class ManualPower:
    """Asks the operator to switch the power and waits for Enter.

    The prompt goes to ``output`` (stderr by default); the answer is one line read from ``input``
    (stdin by default) in the loop's default executor, so the event loop keeps serving the arm
    while the operator walks to the switch. End of input (a closed pipe, Ctrl-D) raises
    :class:`PowerError`. A cancelled wait leaves the reading thread blocked until a line or the end
    of input arrives (a thread cannot be interrupted); the line it then reads is discarded.
    """

    def __init__(self, input: IO[str] | None = None, output: IO[str] | None = None, *,
                 off_prompt: str = "Switch the arm's power OFF, then press Enter",
                 on_prompt: str = "Switch the arm's power ON, then press Enter") -> None:
        self._input = input
        self._output = output
        self.off_prompt = off_prompt
        self.on_prompt = on_prompt

    async def power_off(self) -> None:
        """Prompt for power off; return when the operator pressed Enter."""
        await self._ask(self.off_prompt)

    async def power_on(self) -> None:
        """Prompt for power on; return when the operator pressed Enter."""
        await self._ask(self.on_prompt)

    async def _ask(self, prompt: str) -> None:
        out = self._output if self._output is not None else sys.stderr
        src = self._input if self._input is not None else sys.stdin
        print(f"\n>>> {prompt} ", end="", file=out, flush=True)
        readline: Callable[[], str] = src.readline
        line = await asyncio.get_running_loop().run_in_executor(None, readline)
        if not line:
            raise PowerError(f"power switch: the operator's input closed while waiting for "
                             f"{prompt!r}")

    def __repr__(self) -> str:
        return "ManualPower()"
