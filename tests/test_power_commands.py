"""The power commands ``docs/runner.md`` gives for a lab's relays work as written: the Tasmota
line, run by ``armbench run startup-recovery --power-command`` against the relay ``armbench
emulate --relay`` serves (its Tasmota dialect), cuts the emulated arm's power at each cut; and the
relay answers both its dialects. Real: the HTTP relay, ``curl``, the TCP link to the arm. The
relay's coil cannot be real here: the emulator's power line stands in for it. The uhubctl line
is not run (it needs a hub with per-port power switching); it is only checked to parse."""

from __future__ import annotations

import asyncio
import re
import shlex
import shutil
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from far_end import Emulator
from netutil import free_port

from armbench.bench.runner.power import parse_command
from armbench.fakes.links.relay import RelayServer
from armbench.record import load_record

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "runner.md"
#: Two cuts of a still arm, no EEPROM wear, a live link's patience (for a starved emulator).
CUTS_CONFIG = """\
spec_version = "armbench-limits/1"

[bench]
connect_timeout_s = 30.0
reply_timeout_s = 5.0
move_timeout_scale = 10.0

[suites.startup-recovery]
trials = 2
conditions = ["stopped-near"]
joint_sets = [[2, 3, 4]]
wear_duration_s = 0
"""


def _documented(program: str) -> tuple[str, str]:
    """The ``--power-command OFF ON`` of the docs' line that runs ``program``."""
    text = DOC.read_text(encoding="utf-8")
    block = text[text.index("**Power commands for common relays.**"):]
    line = next(x for x in block.splitlines() if "--power-command" in x and program in x)
    words = shlex.split(line)
    at = words.index("--power-command")
    return words[at + 1], words[at + 2]


def _get(url: str) -> str:
    with urllib.request.urlopen(url, timeout=10) as answer:
        return str(answer.read().decode())


def test_the_relay_speaks_simplerest_and_tasmota() -> None:
    powered = [True]

    def switch(on: bool) -> None:
        powered[0] = on

    async def main() -> list[str]:
        relay = RelayServer(lambda: powered[0], switch, "127.0.0.1", 0)
        host, port = await relay.start()
        base = f"http://{host}:{port}"
        answers = []
        try:
            for path in ("/relay/0/0", "/relay/0", "/cm?cmnd=Power%20On", "/cm?cmnd=Power"):
                answers.append(await asyncio.to_thread(_get, base + path))
            with pytest.raises(urllib.error.HTTPError, match="404"):
                await asyncio.to_thread(_get, base + "/nothing")
        finally:
            await relay.close()
        return answers

    assert asyncio.run(main()) == ["0", "0", '{"POWER": "ON"}', '{"POWER": "ON"}']


def test_the_uhubctl_line_parses() -> None:
    off, on = _documented("uhubctl")
    assert parse_command(off, "off")[:1] == parse_command(on, "on")[:1] == ["uhubctl"]


@pytest.mark.skipif(shutil.which("curl") is None, reason="curl not installed")
def test_the_tasmota_line_cuts_the_arms_power(tmp_path: Path) -> None:
    relay = free_port()
    emulator = Emulator(tmp_path, "tcp", ["-v", "--relay", f"127.0.0.1:{relay}"])
    off, on = (re.sub(r"http://relay\.lab", f"http://127.0.0.1:{relay}", c)
               for c in _documented("cmnd=Power"))
    (tmp_path / "bench.toml").write_text(CUTS_CONFIG, encoding="utf-8")
    emulator.start()
    try:
        done = subprocess.run([sys.executable, "-m", "armbench", "run", "startup-recovery",
                               "--config", "bench.toml", "--port", emulator.port, "--out", "run",
                               "--power-command", off, on], cwd=tmp_path, capture_output=True,
                              text=True, timeout=900, check=False)
    finally:
        emulator.stop()
    assert done.returncode == 0, done.stdout + done.stderr
    suite = load_record(tmp_path / "run" / "results.json").suites["startup-recovery"]
    cuts = [t for t in suite.trials if t.params.get("kind") == "cut"]
    assert len(cuts) == 2 and all(t.status == "done" and t.skipped is None for t in cuts)
    log = emulator.log.read_text(encoding="utf-8")
    assert log.count("relay: power off") == 2 and log.count("relay: power on") == 2
