"""``armbench emulate --pty --link PATH`` never destroys what is at PATH (issue 20, first item).

The device node of a real arm is stood in for by a FIFO (``os.mkfifo``), which is a special file
as a ``mknod`` character device is, and needs no privilege.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from armbench.cli.main import main
from armbench.fakes.links.pty_link import LinkError, claim_link, release_link

ROOT = Path(__file__).resolve().parents[1]


def _file(p: Path) -> None:
    p.write_text("a user's notes\n", encoding="utf-8")


def _fifo(p: Path) -> None:
    os.mkfifo(p)


def _folder(p: Path) -> None:
    p.mkdir()
    (p / "inside").write_text("x", encoding="utf-8")


def _foreign_link(p: Path) -> None:
    p.symlink_to("/etc/hostname")


MAKERS: dict[str, Callable[[Path], None]] = {
    "regular file": _file, "special file": _fifo, "folder": _folder,
    "symlink elsewhere": _foreign_link,
}


def _snapshot(p: Path) -> tuple[int, str]:
    st = os.lstat(p)
    target = os.readlink(p) if p.is_symlink() else ""
    return st.st_mode, target


@pytest.mark.parametrize("kind", sorted(MAKERS))
def test_claim_refuses_anything_not_an_emulator_link(tmp_path: Path, kind: str) -> None:
    link = tmp_path / "ttyUSB0"
    MAKERS[kind](link)
    before = _snapshot(link)
    with pytest.raises(LinkError, match=str(link)):
        claim_link(link, "/dev/pts/7")
    assert _snapshot(link) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ttyUSB0"]  # no staging file left


def test_claim_replaces_an_earlier_emulator_link_and_release_removes_only_its_own(
        tmp_path: Path) -> None:
    link = tmp_path / "arm"
    link.symlink_to("/dev/pts/999")  # a stale link left by an emulator that was killed
    claim_link(link, "/dev/pts/3")
    assert os.readlink(link) == "/dev/pts/3"
    release_link(link, "/dev/pts/4")  # not ours any more (another emulator took it): kept
    assert os.readlink(link) == "/dev/pts/3"
    release_link(link, "/dev/pts/3")
    assert not os.path.lexists(link)


def test_release_leaves_a_file_put_in_place_of_the_link(tmp_path: Path) -> None:
    link = tmp_path / "arm"
    claim_link(link, "/dev/pts/3")
    link.unlink()
    _file(link)
    release_link(link, "/dev/pts/3")
    assert link.read_text(encoding="utf-8") == "a user's notes\n"


def test_claim_into_a_missing_folder_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(LinkError, match="does not exist"):
        claim_link(tmp_path / "nowhere" / "arm", "/dev/pts/3")


@pytest.mark.parametrize("kind", ["regular file", "special file"])
def test_cli_refuses_with_one_line_and_status_2(tmp_path: Path, kind: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    link = tmp_path / "ttyUSB0"
    MAKERS[kind](link)
    before = _snapshot(link)
    assert main(["emulate", "--pty", "--link", str(link), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(link) in err
    assert _snapshot(link) == before


def test_cli_in_a_process_keeps_the_file(tmp_path: Path) -> None:
    link = tmp_path / "notes.txt"
    _file(link)
    proc = subprocess.run([sys.executable, "-m", "armbench", "emulate", "--pty", "--link",
                           str(link), "--duration", "0.1"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "refusing" in proc.stderr and "Traceback" not in proc.stderr
    assert link.read_text(encoding="utf-8") == "a user's notes\n"


@pytest.mark.skipif(shutil.which("avr-gcc") is None, reason="no AVR toolchain")
@pytest.mark.parametrize("kind", ["symlink elsewhere", "regular file"])
def test_firmware_in_the_loop_keeps_what_is_at_the_link(tmp_path: Path, kind: str,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    """``emulate --firmware`` made its own link: it deleted any symlink there (a file was a
    traceback); it now claims the link as ``--pty`` does."""
    link = tmp_path / "ttyUSB0"
    MAKERS[kind](link)
    before = _snapshot(link)
    assert main(["emulate", "--firmware", "", "--pty", "--link", str(link),
                 "--duration", "0.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines()[-1].startswith("armbench emulate: error: --link") and "refusing" in err
    assert _snapshot(link) == before


def test_pty_without_termios_is_one_line() -> None:
    """Where ``termios`` is missing (Windows; made unimportable here), ``--pty`` says what it
    needs instead of a ``ModuleNotFoundError`` traceback."""
    code = ("import sys; sys.modules['termios'] = None; from armbench.cli.main import main; "
            "sys.exit(main(['emulate', '--pty', '--duration', '0.1']))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=60, check=False)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "armbench emulate: error: --pty needs a POSIX pseudo-terminal; use --tcp HOST:PORT "
        "(this Python has no termios)"]
