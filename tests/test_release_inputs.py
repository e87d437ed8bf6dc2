"""Inputs of the adversarial round on the release build (``docs/reliability.md``, third round):
each bad input is one line naming it, exit status 2, before any work, and nothing of the user's
(or of the installed package) written. Real files, FIFOs and processes throughout.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from armbench.cli.main import main


def _refused(capsys: pytest.CaptureFixture[str], *argv: str | Path) -> str:
    """Run ``armbench ARGV`` in this process: exit status 2 and one line on stderr, returned."""
    status = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert status == 2, err
    assert len(err.strip().splitlines()) == 1, err
    return err


# --- settings ------------------------------------------------------------------------------------

@pytest.mark.parametrize(("value", "problem"), [
    ("1.5", "1.5 must be a whole number of encoder counts 0..64"),
    ("100000", "100000 must be a whole number of encoder counts 0..64"),
    ("-1", "-1 must be a whole number of encoder counts 0..64"),
])
def test_a_deadband_is_a_bounded_whole_number(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              value: str, problem: str) -> None:
    settings = tmp_path / "robot.toml"
    settings.write_text(f"[emulator]\ndeadband_counts = {value}\n")
    err = _refused(capsys, "run", "accuracy", "--settings", settings, "--out", tmp_path / "run")
    assert f"emulator.deadband_counts: {problem}" in err
    assert not (tmp_path / "run").exists()
