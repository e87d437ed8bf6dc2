"""A light command pays only for what it uses: ``armbench --help`` and ``armbench fk`` import none
of the heavy libraries (checked with ``python -X importtime``, not timed: the times are figures of
``armbench perf --only startup``), and every command's ``--help`` still works."""

from __future__ import annotations

import subprocess
import sys

import pytest

import armbench
from armbench.cli import main as cli
from armbench.cli.perf.startup_perf import heavy_imports


@pytest.mark.parametrize("args", [("--help",), ("fk", "0", "0", "0", "0"), ("fk", "--help")])
def test_a_light_command_imports_no_heavy_library(args: tuple[str, ...]) -> None:
    assert heavy_imports(("-m", "armbench", *args)) == []


def test_the_help_lists_every_command_with_its_line(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        cli.main(["--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    for name, (_, help_line) in cli.COMMANDS.items():
        assert name in out and help_line.split()[0] in out


@pytest.mark.parametrize("name", sorted(cli.COMMANDS))
def test_every_command_has_its_help(name: str) -> None:
    done = subprocess.run([sys.executable, "-m", "armbench", name, "--help"], capture_output=True,
                          text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert f"usage: armbench {name}" in done.stdout


def test_every_module_registers_what_the_table_names() -> None:
    """The full parser (every module registered) has exactly the commands of the table."""
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(sub.choices) == set(cli.COMMANDS)  # type: ignore[arg-type]


def test_verbosity_and_version_before_and_after_the_command(
        capsys: pytest.CaptureFixture[str]) -> None:
    parser = cli.build_parser(["fk", "0", "0", "0", "0", "-v", "-v"])
    args = parser.parse_args(["-q", "fk", "0", "0", "0", "0", "-v", "-v"])
    assert (args.verbose, args.quiet) == (2, 1)
    with pytest.raises(SystemExit):
        cli.main(["--version"])
    assert capsys.readouterr().out.strip() == f"armbench {armbench.__version__}"
