"""armbench loads on a system without POSIX's terminal, file-control and resource modules
(Windows): with ``fcntl``, ``termios``, ``pty``, ``tty`` and ``resource`` unimportable, every
module imports and every command's ``--help`` works. What needs them (a pty, ``i2c scan --bus``,
pyserial's POSIX backend) imports them where it is used. Servers stop on Ctrl-C whether or not the
loop has Unix signal handlers."""

from __future__ import annotations

import asyncio
import json
import signal
import subprocess
import sys
from collections.abc import Callable

import pytest

from armbench.cli.main import COMMANDS
from armbench.fakes.links.signals import stop_on_signals

#: Run in a fresh interpreter: import every module of armbench, then every command's --help.
_PROBE = """
import contextlib, importlib, io, json, pkgutil, sys
for name in ("fcntl", "termios", "pty", "tty", "resource"):
    sys.modules[name] = None  # import raises ImportError, as where the module does not exist
import armbench
from armbench.cli import main as cli
failed = {}
for info in pkgutil.walk_packages(armbench.__path__, "armbench."):
    if info.name.startswith("armbench.firmware"):
        continue  # C sources, no Python
    try:
        importlib.import_module(info.name)
    except Exception as exc:
        failed[info.name] = f"{type(exc).__name__}: {exc}"
helps = {}
for command in cli.COMMANDS:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        try:
            cli.main([command, "--help"])
        except SystemExit as exc:
            helps[command] = [exc.code, out.getvalue()[:60]]
print(json.dumps({"failed": failed, "helps": helps}))
"""


def test_every_module_and_command_help_without_posix_terminal_modules() -> None:
    done = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True,
                          timeout=300, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.splitlines()[-1])
    assert result["failed"] == {}
    assert set(result["helps"]) == set(COMMANDS)
    for command, (code, text) in result["helps"].items():
        assert code == 0 and text.startswith(f"usage: armbench {command}"), (command, text)


class _WindowsLikeLoop(asyncio.SelectorEventLoop):
    """A loop without Unix signal handlers, as Windows' loops are."""

    def add_signal_handler(self, sig: int, callback: Callable[..., object],
                           *args: object) -> None:
        raise NotImplementedError


@pytest.mark.parametrize("loop_class", [asyncio.SelectorEventLoop, _WindowsLikeLoop])
def test_a_signal_stops_the_server_with_either_kind_of_loop(
        loop_class: type[asyncio.AbstractEventLoop]) -> None:
    async def body() -> None:
        before = signal.getsignal(signal.SIGINT)  # asyncio.Runner's own, inside run()
        stop = asyncio.Event()
        with stop_on_signals(stop):
            signal.raise_signal(signal.SIGINT)
            async with asyncio.timeout(5.0):
                await stop.wait()
        assert signal.getsignal(signal.SIGINT) is before

    with asyncio.Runner(loop_factory=loop_class) as runner:
        runner.run(body())
