"""Firmware in the loop: build the reference firmware and the simavr harness, run them.

``firmware/`` holds the paper's firmware as AVR C (one source, ``-DJOINT=1..4``) and
``firmware/harness/`` a C program on libsimavr that runs four ATmega328P in lockstep with the I²C
bus, joints, pty and power control (``docs/firmware.md``). This module is their Python side:
:func:`build` compiles both with the system toolchain into a cache folder, :func:`find_images`
names the four images a ``firmware=`` value points to, :func:`board_specs` turns the robot
settings into the harness's joint arguments and :class:`Harness` runs the harness process and
talks to its control channel (power, re-referencing, statistics).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs

from armbench.drivers.model.errors import ArmbenchError, TransportError
from armbench.drivers.model.settings import JointSettings, RobotSettings, load_settings
from armbench.drivers.transports.capabilities import Capabilities
from armbench.drivers.transports.url_parts import split_port
from armbench.fakes.twin.physics import end_stop_steps

__all__ = [
    "AVR_FORM",
    "DEBIAN_PACKAGES",
    "FIRMWARE_SOURCE",
    "LOCKSTEP_CAPABILITIES",
    "FirmwareError",
    "Harness",
    "board_specs",
    "build",
    "cache_dir",
    "data_symbols",
    "find_images",
    "firmware_defines",
    "parse_avr_url",
    "stats_address",
]

_KNOWN = {"firmware", "settings", "eeprom", "control"}
#: What an ``avr://`` port holds.
AVR_FORM = "avr://[?firmware=DIR&settings=FILE&eeprom=DIR&control=FIFO]"

#: What ``avr://`` can do on a virtual-time loop, the boards in lockstep with it
#: (:class:`~armbench.fakes.avr.lockstep.AvrVirtualTransport`): fresh per trial, in workers, with
#: truth from the joint model and their own power switch; no faults, no I²C bus of the host's.
LOCKSTEP_CAPABILITIES = Capabilities(clock="virtual", fresh_per_trial=True, parallel=True,
                                     truth=True, power=True)


def parse_avr_url(port: str) -> tuple[RobotSettings, str | None, Path | None, Path | None]:
    """Robot settings, firmware, EEPROM folder and control FIFO named by an ``avr://`` URL; an
    unknown query parameter, or anything but a query after ``avr://``, is refused naming it."""
    parts = split_port(port, AVR_FORM, address=False, query=True)
    if parts.scheme.lower() != "avr":
        raise TransportError(port, "not an avr:// port")
    query = parse_qs(parts.query, keep_blank_values=True)
    for key in query:
        if key not in _KNOWN:
            raise TransportError(port, f"unknown query parameter {key!r} "
                                       f"(known: {', '.join(sorted(_KNOWN))})")
    robot = load_settings(query["settings"][-1]) if "settings" in query else RobotSettings()
    firmware = query["firmware"][-1] if "firmware" in query else None
    eeprom = Path(query["eeprom"][-1]) if "eeprom" in query else None
    control = Path(query["control"][-1]) if "control" in query else None
    return robot, firmware, eeprom, control


#: Where the firmware and harness sources live (the checkout's ``firmware/``).
FIRMWARE_SOURCE = Path(__file__).resolve().parents[2] / "firmware"

#: Debian packages of the toolchain, named in the error when one is missing.
DEBIAN_PACKAGES = "gcc-avr avr-libc simavr libsimavr-dev gcc"

# -g: line tables for the fuzzer's coverage (fuzz/fuzz_differential.py); the code is the same
_AVR_CFLAGS = ("-mmcu=atmega328p", "-DF_CPU=16000000UL", "-Os", "-g", "-std=gnu11", "-Wall",
               "-Wextra", "-Werror")
_AVR_SOURCES = ("main.c", "joint.c", "master.c", "slave.c")
HARNESS_NAME = "armfw-harness"


class FirmwareError(ArmbenchError):
    """The firmware or the harness cannot be built, found or started."""


def cache_dir() -> Path:
    """``$XDG_CACHE_HOME/armbench/firmware`` (``~/.cache/...``): build output, never the source."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "armbench" / "firmware"


def firmware_defines(robot: RobotSettings) -> tuple[str, ...]:
    """The compiler's ``-D`` options that build the reference firmware with the robot's
    ``[emulator]`` choices the firmware has (``deadband_counts``, ``stop_rule``): none for the
    defaults, so the default build is the one without them."""
    from armbench.fakes.firmware.emulator_settings import EmulatorSettings, emulator_settings

    emu, default = emulator_settings(robot), EmulatorSettings()
    out = []
    if emu.deadband_counts != default.deadband_counts:
        out.append(f"-DDEADBAND_COUNTS={emu.deadband_counts}")
    if emu.stop_rule == "reach":
        out.append("-DSTOP_RULE_REACH=1")
    return tuple(out)


def _source_digest(src: Path, defines: Sequence[str] = ()) -> str:
    h = hashlib.sha256(" ".join([*_AVR_CFLAGS, *defines]).encode())
    for path in sorted(src.rglob("*")):
        if path.suffix in (".c", ".h") and path.is_file():
            h.update(str(path.relative_to(src)).encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _require_toolchain() -> None:
    missing = [tool for tool in ("avr-gcc", "avr-objcopy", "avr-nm", "cc")
               if shutil.which(tool) is None]
    if not Path("/usr/include/simavr/sim_avr.h").exists() and not _has_simavr_headers():
        missing.append("simavr headers (sim_avr.h)")
    if missing:
        raise FirmwareError(f"cannot build the firmware: {', '.join(missing)} not found; "
                            f"install the Debian packages: apt-get install {DEBIAN_PACKAGES}")


def _has_simavr_headers() -> bool:
    return any(Path(p, "simavr", "sim_avr.h").exists()
               for p in os.environ.get("CPATH", "").split(os.pathsep) if p)


def _run(cmd: Sequence[str], cwd: Path) -> None:
    proc = subprocess.run(list(cmd), cwd=cwd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise FirmwareError(f"build failed: {' '.join(cmd)}\n{proc.stderr.strip()}")


def build(source: Path = FIRMWARE_SOURCE, out: Path | None = None, *,
          force: bool = False, defines: Sequence[str] = ()) -> Path:
    """Compile the four firmware images (``jointN.elf``/``.hex``, with the compiler options
    ``defines``, :func:`firmware_defines`) and the harness into ``out`` (default: a folder of
    :func:`cache_dir` named by the sources' and options' digest); returns it. An up-to-date
    build is reused unless ``force``."""
    source = source.absolute()  # the compiler runs in ``source``: every path it is given
    if not (source / "firmware.h").is_file():
        raise FirmwareError(f"{source}: no firmware sources here (firmware.h missing)")
    _require_toolchain()
    # relative to the working directory, never to ``source``, where the compiler runs
    out = out.absolute() if out is not None else cache_dir() / _source_digest(source, defines)
    done = out / ".complete"
    if done.exists() and not force:
        return out
    try:
        with _build_lock(out):
            if done.exists() and not force:  # built by whoever held the lock before us
                return out
            done.unlink(missing_ok=True)
            _build_into(source, out, defines)
            done.write_text("ok\n")
    except OSError as exc:  # a file in the way, a place nothing can be made
        raise FirmwareError(f"cannot build into {out}: {exc.strerror or exc}") from None
    return out


@contextlib.contextmanager
def _build_lock(out: Path) -> Iterator[None]:
    """Held while a build writes ``out``: builds of one folder at the same time (parallel test
    workers, two runs starting together) take turns, and the later one finds the earlier's
    images complete instead of rewriting them under a harness that runs them."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.parent / f".{out.name}.lock", "w") as lock:
        if sys.platform != "win32":  # the toolchain is POSIX's; Windows has no flock
            import fcntl

            fcntl.flock(lock, fcntl.LOCK_EX)
        yield


def _build_into(source: Path, out: Path, defines: Sequence[str]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for joint in range(1, 5):
        elf = out / f"joint{joint}.elf"
        _run(["avr-gcc", *_AVR_CFLAGS, *defines, f"-DJOINT={joint}", "-o", str(elf),
              *_AVR_SOURCES], source)
        _run(["avr-objcopy", "-O", "ihex", "-R", ".eeprom", str(elf),
              str(out / f"joint{joint}.hex")], source)
    harness_sources = sorted(str(p.relative_to(source)) for p in (source / "harness").glob("*.c"))
    _run(["cc", "-O2", "-std=gnu11", "-Wall", "-Wextra", "-Werror", "-o",
          str(out / HARNESS_NAME), *harness_sources, "-lsimavr"], source)


def find_images(firmware: str | Path | None, robot: RobotSettings | None = None) -> list[Path]:
    """The four images (joint 1..4) that ``firmware`` names: a folder holding ``jointN.elf`` or
    ``jointN.hex`` (the build's layout), a path with ``{n}`` for the joint number, or None or
    ``""`` for the reference firmware (built if needed, with ``robot``'s
    :func:`firmware_defines`; images of a user's firmware are what they are)."""
    if firmware is None or str(firmware) == "":
        folder = build(defines=() if robot is None else firmware_defines(robot))
        return [folder / f"joint{n}.elf" for n in range(1, 5)]
    text = str(firmware)
    if "{n}" in text:
        images = [Path(text.replace("{n}", str(n))) for n in range(1, 5)]
    else:
        folder = Path(text)
        if not folder.is_dir():
            raise FirmwareError(f"firmware {text!r}: not a folder of joint1..4 images and no "
                                "'{n}' in the name (e.g. build/joint{n}.hex)")
        images = []
        for n in range(1, 5):
            found = [folder / f"joint{n}{ext}" for ext in (".elf", ".hex")
                     if (folder / f"joint{n}{ext}").is_file()]
            if not found:
                raise FirmwareError(f"firmware {text!r}: no joint{n}.elf or joint{n}.hex in it")
            images.append(found[0])
    for image in images:
        if not image.is_file():
            raise FirmwareError(f"firmware image {str(image)!r} does not exist")
        if image.suffix not in (".elf", ".hex"):
            raise FirmwareError(f"firmware image {str(image)!r}: not a .elf or .hex file")
    return images


@functools.lru_cache(maxsize=64)
def _symbols(image: str, mtime_ns: int) -> dict[str, int]:
    """Data addresses of an ELF image's variables (avr-nm, once per image and version)."""
    del mtime_ns  # part of the cache key: a rebuilt image is read again
    out = subprocess.run(["avr-nm", image], capture_output=True, text=True, check=False).stdout
    return {m.group(2): int(m.group(1), 16) & 0xFFFF
            for m in re.finditer(r"^([0-9a-fA-F]+) [bBdD] (\w+)$", out, re.MULTILINE)}


def stats_address(image: Path) -> int:
    """Data address of the firmware's ``fw_stats`` (0 when unknown: a .hex or no such symbol)."""
    return data_symbols(image, ("fw_stats",)).get("fw_stats", 0)


def data_symbols(image: Path, names: Sequence[str]) -> dict[str, int]:
    """Data addresses of the named variables of an ELF image (static ones too), from its symbol
    table; names it lacks are left out (a .hex has none)."""
    if image.suffix != ".elf" or shutil.which("avr-nm") is None or not image.is_file():
        return {}
    found = _symbols(str(image), image.stat().st_mtime_ns)
    return {name: found[name] for name in names if name in found}


def _joint_spec(joint: JointSettings, motor_steps: int) -> list[int]:
    per_rad = joint.steps_per_rad
    c = joint.counts_per_step
    lower, upper = end_stop_steps(joint)  # the Python emulator's end stops
    return [lower, upper, round(joint.hall_rad * per_rad), c.numerator, c.denominator,
            motor_steps]


def board_specs(robot: RobotSettings, images: Sequence[Path],
                motor_steps: Sequence[int] = (0, 0, 0, 0)) -> list[str]:
    """The harness's four ``--board`` values: image, limits, Hall, encoder ratio, start position
    (microsteps, as ``fakes/twin/joint.py`` rounds them) and the ``fw_stats`` address."""
    specs = []
    for joint, image, steps in zip(robot.joints, images, motor_steps, strict=True):
        fields = [str(image), *map(str, _joint_spec(joint, steps)), hex(stats_address(image))]
        specs.append(",".join(fields))
    return specs


@dataclass
class Harness:
    """One running harness process: joint 1's UART on :attr:`pty`, control on its stdin."""

    process: asyncio.subprocess.Process
    pty: str

    @classmethod
    async def start(cls, robot: RobotSettings, firmware: str | Path | None = None, *,
                    speed: str = "realtime", eeprom_dir: Path | None = None,
                    harness: Path | None = None, boot_ms: float = 100.0,
                    control: Path | None = None) -> Harness:
        """Build if needed, start the harness on a new pty and wait until the cores run.
        ``control``: a FIFO (made if missing) that takes the same commands as the harness's
        stdin, e.g. ``echo power off > FIFO`` from a bench's power commands."""
        images = find_images(firmware, robot)
        exe = harness if harness is not None else build() / HARNESS_NAME
        args = ["--pty", "--speed", speed, "--boot-ms", str(boot_ms)]
        if eeprom_dir is not None:
            eeprom_dir.mkdir(parents=True, exist_ok=True)
            args += ["--eeprom-dir", str(eeprom_dir)]
        if control is not None:
            if not control.exists():
                os.mkfifo(control)
            args += ["--control", str(control)]
        for spec in board_specs(robot, images):
            args += ["--board", spec]
        proc = await asyncio.create_subprocess_exec(
            str(exe), *args, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE)
        assert proc.stdout is not None
        pty = ""
        while True:
            line = (await proc.stdout.readline()).decode()
            if not line:
                await proc.wait()
                raise FirmwareError(f"harness exited with status {proc.returncode} at start-up")
            if line.startswith("pty "):
                pty = line[4:].strip()
            elif line.startswith("ready"):
                return cls(proc, pty)

    async def command(self, line: str) -> None:
        """Send one control line (``power off``, ``power on``)."""
        assert self.process.stdin is not None
        self.process.stdin.write(line.encode() + b"\n")
        await self.process.stdin.drain()

    async def stats(self) -> dict[str, Any]:
        """The harness's figures now (``docs/firmware.md``: ISR cycles, periods, I²C times)."""
        await self.command("stats")
        assert self.process.stdout is not None
        while True:
            line = (await self.process.stdout.readline()).decode()
            if not line:
                raise FirmwareError("harness exited")
            if line.startswith("stats "):
                result: dict[str, Any] = json.loads(line[6:])
                return result

    async def power(self, on: bool) -> None:
        """Cut or restore the power of all four boards (EEPROM and motor positions survive)."""
        await self.command("power on" if on else "power off")

    async def re_reference(self) -> None:
        """While the power is off: every joint turned back to its zero position and every EEPROM
        blanked (``home``, ``eeprom blank``), what a lab does by hand to an arm whose start-up
        recovery stalled; at power-up the firmware counts from zero where the joints stand."""
        await self.command("eeprom blank")
        await self.command("home")

    async def stop(self) -> None:
        """Quit the harness (its EEPROM files are written) and wait for it."""
        if self.process.returncode is None:
            try:
                await self.command("quit")
                async with asyncio.timeout(5.0):
                    await self.process.wait()
            except (TimeoutError, BrokenPipeError, ConnectionResetError):
                self.process.kill()
                await self.process.wait()
