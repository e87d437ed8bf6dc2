"""Headless Chromium driven over the DevTools protocol, for the report tests.

Chromium runs with ``--remote-debugging-pipe``: it reads DevTools commands on fd 3 and writes
replies and events on fd 4, JSON messages ended by a NUL byte, so a few lines of standard library
speak to it (no websocket).
"""

from __future__ import annotations

import base64
import contextlib
import fcntl
import json
import os
import select
import shutil
import signal
import time
from pathlib import Path
from typing import Any

CHROMIUM = shutil.which("chromium") or next(
    (p for p in ("/usr/bin/chromium", "/usr/bin/chromium-browser") if os.path.exists(p)), None)
TIMEOUT_S = 30.0

#: Sizes and layout facts the page reports about itself (evaluated in the page).
PROBE = """JSON.stringify({
  first: ['verdict', 'scorecard'].map(id => { const e = document.getElementById(id);
    if (!e) return null; const r = e.getBoundingClientRect(); return [r.top, r.bottom]; }),
  firstSvg: (() => { const s = document.querySelector('svg');
    if (!s) return null; const r = s.getBoundingClientRect(); return [r.top, r.bottom]; })(),
  innerHeight: window.innerHeight,
  svgs: Array.from(document.querySelectorAll('svg')).map(s => {
    const r = s.getBoundingClientRect(); return [r.width, r.height]; }),
  texts: Array.from(document.querySelectorAll('svg text')).map(t => t.getBBox().width > 0),
  scrollWidth: document.documentElement.scrollWidth,
  innerWidth: window.innerWidth,
  scripts: document.scripts.length,
  verdict: (document.getElementById('verdict') || {innerText: ''}).innerText,
  nav: (() => { const n = document.querySelector('nav');
                return n ? getComputedStyle(n).display : null; })(),
  overflowing: Array.from(document.querySelectorAll('section, header, figure, dl, p'))
    .filter(e => e.getBoundingClientRect().right > window.innerWidth + 1).length,
})"""


class Chromium:
    """One headless Chromium speaking the DevTools protocol over a pipe."""

    def __init__(self, workdir: Path) -> None:
        assert CHROMIUM is not None
        cmd_r, cmd_w = os.pipe()  # we write commands; Chromium reads them on fd 3
        evt_r, evt_w = os.pipe()  # Chromium writes on fd 4; we read
        # sources above 4, so the dup2 onto 3 and 4 cannot clobber one another
        hi_r = fcntl.fcntl(cmd_r, fcntl.F_DUPFD_CLOEXEC, 10)
        hi_w = fcntl.fcntl(evt_w, fcntl.F_DUPFD_CLOEXEC, 10)
        os.close(cmd_r)
        os.close(evt_w)
        self.log_path = workdir / "chromium.log"
        log = os.open(self.log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        args = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                "--no-first-run", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--disable-extensions",
                "--hide-scrollbars", "--mute-audio", "--remote-debugging-pipe",
                f"--user-data-dir={workdir / 'profile'}", "about:blank"]
        try:
            self.pid = os.posix_spawn(CHROMIUM, args, dict(os.environ), file_actions=[
                (os.POSIX_SPAWN_OPEN, 0, "/dev/null", os.O_RDONLY, 0),
                (os.POSIX_SPAWN_DUP2, log, 1), (os.POSIX_SPAWN_DUP2, log, 2),
                (os.POSIX_SPAWN_DUP2, hi_r, 3), (os.POSIX_SPAWN_DUP2, hi_w, 4),
            ], setpgroup=0)
        finally:
            os.close(log)
            os.close(hi_r)
            os.close(hi_w)
        self.wfd, self.rfd = cmd_w, evt_r
        self.buf = b""
        self.next_id = 0
        self.events: list[dict[str, Any]] = []
        self.session: str | None = None

    # -- protocol ----------------------------------------------------------------------

    def _read(self, deadline: float) -> dict[str, Any]:
        while b"\0" not in self.buf:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f"Chromium did not answer; see {self.log_path}")
            ready, _, _ = select.select([self.rfd], [], [], remaining)
            if ready:
                chunk = os.read(self.rfd, 1 << 20)
                if not chunk:
                    raise EOFError(f"Chromium closed the pipe; see {self.log_path}")
                self.buf += chunk
        message, _, self.buf = self.buf.partition(b"\0")
        result: dict[str, Any] = json.loads(message)
        return result

    def call(self, method: str, params: dict[str, Any] | None = None, *,
             browser: bool = False) -> dict[str, Any]:
        """Send a command (to the attached page unless ``browser``) and wait for its reply;
        events arriving meanwhile are kept in ``events``."""
        self.next_id += 1
        msg: dict[str, Any] = {"id": self.next_id, "method": method, "params": params or {}}
        if not browser and self.session is not None:
            msg["sessionId"] = self.session
        data = json.dumps(msg).encode() + b"\0"
        while data:
            data = data[os.write(self.wfd, data):]
        deadline = time.monotonic() + TIMEOUT_S
        while True:
            reply = self._read(deadline)
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                result: dict[str, Any] = reply.get("result", {})
                return result
            if "method" in reply:
                self.events.append(reply)

    def wait_event(self, method: str) -> dict[str, Any]:
        deadline = time.monotonic() + TIMEOUT_S
        while True:
            for i, e in enumerate(self.events):
                if e["method"] == method:
                    return self.events.pop(i)
            reply = self._read(deadline)
            if "method" in reply:
                self.events.append(reply)

    # -- conveniences --------------------------------------------------------------------

    def open_page(self) -> None:
        target = self.call("Target.createTarget", {"url": "about:blank"}, browser=True)
        attached = self.call("Target.attachToTarget",
                             {"targetId": target["targetId"], "flatten": True}, browser=True)
        self.session = attached["sessionId"]
        for domain in ("Runtime", "Log", "Page", "Network"):
            self.call(f"{domain}.enable")

    def load(self, url: str, width: int = 1280, height: int = 900) -> None:
        self.viewport(width, height)
        self.events.clear()
        self.call("Page.navigate", {"url": url})
        self.wait_event("Page.loadEventFired")

    def viewport(self, width: int, height: int, *, mobile: bool = False) -> None:
        self.call("Emulation.setDeviceMetricsOverride",
                  {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": mobile})

    def probe(self) -> dict[str, Any]:
        result = self.call("Runtime.evaluate", {"expression": PROBE, "returnByValue": True})
        assert "exceptionDetails" not in result, result
        value: dict[str, Any] = json.loads(result["result"]["value"])
        return value

    def screenshot(self, path: Path, *, max_height: int = 24_000) -> None:
        metrics = self.call("Page.getLayoutMetrics")
        size = metrics["cssContentSize"]
        clip = {"x": 0, "y": 0, "width": size["width"],
                "height": min(size["height"], max_height), "scale": 1}
        shot = self.call("Page.captureScreenshot",
                         {"format": "png", "captureBeyondViewport": True, "clip": clip})
        path.write_bytes(base64.b64decode(shot["data"]))

    def problems(self) -> list[str]:
        """Console messages, exceptions and log entries worth failing for."""
        out = []
        for e in self.events:
            p = e.get("params", {})
            if e["method"] == "Runtime.consoleAPICalled":
                out.append(f"console.{p.get('type')}: {p.get('args')}")
            elif e["method"] == "Runtime.exceptionThrown":
                out.append(f"exception: {p.get('exceptionDetails')}")
            elif e["method"] == "Log.entryAdded":
                entry = p.get("entry", {})
                if entry.get("level") in ("error", "warning"):
                    out.append(f"log {entry.get('source')}/{entry.get('level')}: "
                               f"{entry.get('text')} {entry.get('url', '')}")
        return out

    def requests(self) -> list[str]:
        return [e["params"]["request"]["url"] for e in self.events
                if e["method"] == "Network.requestWillBeSent"]

    def close(self) -> None:
        with contextlib.suppress(OSError, EOFError, TimeoutError, RuntimeError):
            self.call("Browser.close", browser=True)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            pid, _ = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                break
            time.sleep(0.05)
        else:  # still running: end the process group this test started, and reap it
            os.killpg(self.pid, signal.SIGKILL)
            os.waitpid(self.pid, 0)
        os.close(self.wfd)
        os.close(self.rfd)


