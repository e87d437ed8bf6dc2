"""Power from the lab: a start-up recovery run over ``labgrid://PLACE`` cuts the arm's power
through the place's own power resource, with no ``--power-command``.

Real: a labgrid coordinator and exporter on loopback; the place's ``RawSerialPort`` (an
``armbench emulate --pty`` arm, served through ser2net) and its ``NetworkPowerPort`` (model
``simplerest``, the exporter publishing it); labgrid's client switching it (``labgrid-client power
off|on``, its ``NetworkPowerDriver`` sending HTTP requests); the HTTP relay ``armbench emulate
--relay`` serves, which cuts and restores the emulated arm's power line. What cannot be real
here is the relay's coil and the arm's supply: the emulator's power line stands in for them.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from netutil import free_port

pytest.importorskip("labgrid", reason="an optional extra: pip install 'armbench[labgrid]'")
if shutil.which("ser2net") is None and not os.path.exists("/usr/sbin/ser2net"):
    pytest.skip("ser2net not installed (Debian package 'ser2net'): the exporter serves the arm "
                "with it", allow_module_level=True)

from test_labgrid import Lab, _stop, _wait, start_coordinator, start_exporter
from test_power_commands import CUTS_CONFIG

from armbench.record import load_record

ROOT = Path(__file__).resolve().parents[1]
PLACE = "arm-p"
#: Two cuts of a still arm (judged), no EEPROM wear; the live link's patience.
CONFIG = CUTS_CONFIG + """
[limits."startup.expected_success_rate_pct"]
low = 100.0
unit = "%"
"""


@pytest.fixture(scope="module")
def powered_lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Lab, Path]]:
    """A coordinator, an emulated arm with its relay, an exporter serving both, the place."""
    folder = tmp_path_factory.mktemp("lab")
    procs: list[subprocess.Popen[bytes]] = []
    relay_log = folder / "emulate.log"
    try:
        coordinator = start_coordinator(folder, procs)
        relay = free_port()
        with relay_log.open("wb") as log:
            emulator = subprocess.Popen([sys.executable, "-m", "armbench", "-v", "emulate",
                                         "--pty", "--relay", f"127.0.0.1:{relay}"],
                                        cwd=ROOT, stdout=subprocess.PIPE, stderr=log)
        procs.append(emulator)
        assert emulator.stdout is not None
        device = emulator.stdout.readline().decode().split(" on ")[-1].strip()
        assert device.startswith("/dev/pts/"), device
        assert "power relay on" in emulator.stdout.readline().decode()
        (folder / "exporter.yaml").write_text(
            f"{PLACE}:\n  RawSerialPort:\n    port: {device}\n    speed: 115200\n"
            "  NetworkPowerPort:\n    model: simplerest\n"
            f"    host: 'http://127.0.0.1:{relay}/relay/{{index}}/{{value}}'\n    index: 0\n",
            encoding="utf-8")
        lab = start_exporter(folder, coordinator, procs)
        _wait(lambda: all(f"bench-pc/{PLACE}/{cls}" in lab.client("resources").stdout
                          for cls in ("NetworkSerialPort", "NetworkPowerPort")),
              "the exporter publishes the serial port and the power port")
        for args in (("create",), ("add-match", f"bench-pc/{PLACE}/*")):
            done = lab.client("-p", PLACE, *args)
            assert done.returncode == 0, done.stderr
        yield lab, relay_log
    finally:
        _stop(procs)


def test_a_startup_recovery_run_cuts_power_through_the_place(
        powered_lab: tuple[Lab, Path], tmp_path: Path) -> None:
    lab, relay_log = powered_lab
    (tmp_path / "bench.toml").write_text(CONFIG, encoding="utf-8")
    before = relay_log.read_text(encoding="utf-8").count("relay: power off")
    done = subprocess.run([sys.executable, "-m", "armbench", "run", "startup-recovery",
                           "--config", "bench.toml", "--port", lab.port(PLACE), "--out", "run"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=900,
                          check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    record = load_record(tmp_path / "run" / "results.json")
    suite = record.suites["startup-recovery"]
    cuts = [t for t in suite.trials if t.params.get("kind") == "cut"]
    assert len(cuts) == 2 and all(t.status == "done" and t.skipped is None for t in cuts)
    measured = {m.name: m.value for m in suite.measurements}
    assert measured["startup.expected_success_rate_pct"] == 100.0
    # the relay's own log: each cut went through labgrid's client to the emulator's power line
    log = relay_log.read_text(encoding="utf-8")
    assert log.count("relay: power off") - before == 2
    assert log.count("relay: power on") >= 2
    assert lab.client("-p", PLACE, "show").stdout.count("acquired: None") == 1  # released


def test_a_power_command_still_wins_over_the_place(powered_lab: tuple[Lab, Path],
                                                   tmp_path: Path) -> None:
    """``--power-command`` given: the place's resource is left alone."""
    lab, relay_log = powered_lab
    (tmp_path / "bench.toml").write_text(CONFIG.replace("trials = 2", "trials = 1"),
                                         encoding="utf-8")
    before = relay_log.read_text(encoding="utf-8").count("relay: power off")
    done = subprocess.run([sys.executable, "-m", "armbench", "run", "startup-recovery",
                           "--config", "bench.toml", "--port", lab.port(PLACE), "--out", "run",
                           "--power-command", "true", "true"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=900,
                          check=False)
    assert done.returncode in (0, 1), done.stdout + done.stderr  # a relay that switches nothing
    assert relay_log.read_text(encoding="utf-8").count("relay: power off") == before
