"""Start a foreign arm (a simulator written apart from armbench) as a subprocess on a free
loopback port and hand out its ``socket://`` URL.

The arms: ``stall``, ``tracker``, ``jitter``, ``threshold`` (the scripts of this folder) and
``shared`` (the simulator of /work/shared/foreign-arm, found as
``../shared/foreign-arm/foreign_arm.py`` beside the checkout, or ``$ARMBENCH_FOREIGN_ARM``;
:func:`shared_arm_script` is None when it is absent, and a test then skips with the reason
:data:`SHARED_MISSING`).

    with foreign_arm("jitter", "--gear-j3", "38") as arm:
        arm.url        # socket://127.0.0.1:PORT
        arm.tracker    # (host, port) of the tracker stream, when the arm has one
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Final

HERE: Final = Path(__file__).resolve().parent
ROOT: Final = HERE.parents[1]
SCRIPTS: Final = {"stall": HERE / "stall_arm.py", "tracker": HERE / "tracker_arm.py",
                  "jitter": HERE / "jitter_arm.py", "threshold": HERE / "threshold_arm.py"}
SHARED_MISSING: Final = ("the shared foreign arm (../shared/foreign-arm/foreign_arm.py beside the "
                         "checkout, or $ARMBENCH_FOREIGN_ARM) is absent")
#: How long an arm may take to print its listening line on a loaded machine (s).
START_TIMEOUT_S: Final = 60.0


def shared_arm_script() -> Path | None:
    """The shared foreign arm's script, None when it is not on this machine."""
    candidates = [Path(p) for p in (os.environ.get("ARMBENCH_FOREIGN_ARM"),) if p]
    candidates += [ROOT.parent / "shared" / "foreign-arm" / "foreign_arm.py",
                   Path("/work/shared/foreign-arm/foreign_arm.py")]
    return next((p for p in candidates if p.is_file()), None)


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True, slots=True)
class RunningArm:
    """A started arm: its serial URL, its process, its tracker's address (or None)."""

    url: str
    process: subprocess.Popen[bytes]
    tracker: tuple[str, int] | None


def _script(name: str) -> Path:
    if name == "shared":
        script = shared_arm_script()
        if script is None:
            raise FileNotFoundError(SHARED_MISSING)
        return script
    return SCRIPTS[name]


@contextlib.contextmanager
def foreign_arm(name: str, *args: str) -> Iterator[RunningArm]:
    """Run the arm ``name`` with ``args`` on a free port (and, for ``tracker``, its tracker on
    another) until the block ends; waits for its listening line, so the port is open."""
    port = free_port()
    cmd = [sys.executable, str(_script(name)), "--tcp", f"127.0.0.1:{port}", *args]
    tracker = None
    if name == "tracker":
        tracker = ("127.0.0.1", free_port())
        cmd += ["--tracker", f"127.0.0.1:{tracker[1]}"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + START_TIMEOUT_S
        line = b""
        while not line.endswith(b"\n"):
            left = deadline - time.monotonic()
            ready, _, _ = select.select([proc.stdout], [], [], max(0.0, left))
            if not ready or proc.poll() is not None:
                err = proc.stderr.read().decode() if proc.poll() is not None and proc.stderr \
                    else "no listening line in time"
                raise RuntimeError(f"foreign arm {name} did not start: {err.strip()}")
            chunk = os.read(proc.stdout.fileno(), 256)
            if not chunk:
                raise RuntimeError(f"foreign arm {name} closed its output before listening")
            line += chunk
        yield RunningArm(f"socket://127.0.0.1:{port}", proc, tracker)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()
