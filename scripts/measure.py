"""Measure and keep the record: run ``armbench perf`` or one of the figure scripts of
``scripts/`` and write what it printed, with the date, the machine, the commit and the command,
as a new dated file in ``measurements/``, so that measured figures are generated, not typed.

    python scripts/measure.py [--topic NAME] [--note TEXT] [--out-dir DIR] RECIPE [ARGS...]

    perf [ARGS...]              armbench perf --json ARGS
    dask [ARGS...]              scripts/dask_throughput.py ARGS
    ros2 [ARGS...]              scripts/ros2_figures.py ARGS
    foreign-arm NAME OUT [...]  scripts/foreign_arm_figures.py NAME OUT ...
    same-figures A B            scripts/same_figures.py A B
    trial-cpu VARIANT...        scripts/trial_cpu.py VARIANT...
    emulator-share [...]        scripts/emulator_share.py ...
    run -- CMD...               any other command (give it a --topic)

The options come before the recipe: everything after it is the command's.
The file is ``measurements/YYYY-MM-DD-TOPIC.md`` (the recipe's name unless ``--topic`` is given;
``-2``, ``-3``, ... when that name is taken: nothing is ever overwritten). The command's
standard output is kept (the first MiB of it), its standard error passes through to the
terminal as it comes. The exit status is the command's; ``--note TEXT`` adds what the figures
cannot say (what else ran on the machine, why the run was made).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shlex
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = ROOT / "scripts"
#: At most this much of a command's standard output is kept in the file.
MAX_OUTPUT_BYTES = 1 << 20
#: The recipes: each name and the command it runs before the arguments given after it.
RECIPES: dict[str, list[str]] = {
    "perf": [sys.executable, "-m", "armbench", "perf", "--json"],
    "dask": [sys.executable, str(SCRIPTS / "dask_throughput.py")],
    "ros2": [sys.executable, str(SCRIPTS / "ros2_figures.py")],
    "foreign-arm": [sys.executable, str(SCRIPTS / "foreign_arm_figures.py")],
    "same-figures": [sys.executable, str(SCRIPTS / "same_figures.py")],
    "trial-cpu": [sys.executable, str(SCRIPTS / "trial_cpu.py")],
    "emulator-share": [sys.executable, str(SCRIPTS / "emulator_share.py")],
    "run": [],
}
TOPIC = re.compile(r"[a-z0-9][a-z0-9-]{0,59}")


class MeasureError(Exception):
    """A request this script refuses before it runs anything."""


@dataclass(frozen=True)
class Outcome:
    """What one run of a command gave: its exit status, its standard output (bounded) and how
    many bytes of it were left out, its start and end (UTC) and its wall time."""

    status: int
    output: str
    left_out_bytes: int
    started: datetime
    ended: datetime
    wall_s: float


def _git(*args: str) -> str:
    done = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=False)
    return done.stdout.strip() if done.returncode == 0 else ""


def commit_line() -> str:
    """The checkout's commit, its branch, and whether tracked files differ from it."""
    commit = _git("rev-parse", "HEAD")
    if not commit:
        return "not a git checkout"
    branch = _git("rev-parse", "--abbrev-ref", "HEAD") or "detached"
    dirty = _git("status", "--porcelain", "--untracked-files=no")
    changes = "uncommitted changes to tracked files" if dirty else "no uncommitted changes"
    return f"`{commit}` (branch `{branch}`; {changes})"


def build_line() -> str:
    """Which build of armbench runs: compiled (mypyc) or source, as ``armbench perf`` says."""
    try:
        from armbench.cli.perf.hot_modules import build_name
    except ImportError as exc:
        return f"armbench is not importable ({exc})"
    return build_name()


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def machine_line() -> str:
    """The machine: system, kernel, architecture, CPUs and their model, Python."""
    return (f"{platform.system()} {platform.release()} {platform.machine()}, "
            f"{os.cpu_count()} CPUs ({_cpu_model()}), "
            f"{platform.python_implementation()} {platform.python_version()}")


def load_average() -> str:
    """The 1, 5 and 15 minute load averages, where the system keeps them."""
    try:
        return ", ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "unknown"


def run_command(command: Sequence[str]) -> Outcome:
    """Run ``command`` from the checkout, its standard output spooled to a temporary file of
    which the first :data:`MAX_OUTPUT_BYTES` are kept."""
    started = datetime.now(UTC)
    t0 = time.monotonic()
    with tempfile.TemporaryFile() as out:
        status = subprocess.run(list(command), cwd=ROOT, stdout=out, check=False).returncode
        wall_s = time.monotonic() - t0
        size = out.tell()
        out.seek(0)
        kept = out.read(MAX_OUTPUT_BYTES)
    return Outcome(status, kept.decode("utf-8", errors="replace"), size - len(kept), started,
                   datetime.now(UTC), wall_s)


def figure_table(output: str) -> list[str]:
    """``armbench perf --json``'s figures as a Markdown table; nothing for other output."""
    try:
        data = json.loads(output)
    except ValueError:
        return []
    figures = data.get("figures") if isinstance(data, dict) else None
    if not isinstance(figures, list):
        return []
    rows = ["| figure | value | unit | ratio to its bound | note |", "|---|---|---|---|---|"]
    for f in figures:
        if not isinstance(f, dict):
            return []
        value, ratio = f.get("value"), f.get("ratio")
        shown = f"{value:.6g}" if isinstance(value, float) else str(value)
        rows.append(f"| `{f.get('name')}` | {shown} | {f.get('unit', '')} | "
                    f"{'' if ratio is None else f'{ratio:.3g}'} | {f.get('note', '')} |")
    return ["## Figures", "", *rows, ""]


def render(topic: str, command: Sequence[str], outcome: Outcome, *, commit: str, build: str,
           machine: str, load_before: str, load_after: str, note: str) -> str:
    """The Markdown of one measurement."""
    shown = shlex.join(["python" if c == sys.executable else c for c in command])
    shown = shown.replace(str(ROOT) + "/", "")
    rows = [
        ("date (UTC)", f"{outcome.started:%Y-%m-%d %H:%M:%S} to {outcome.ended:%H:%M:%S} "
                       f"({outcome.wall_s:.1f} s of wall time)"),
        ("command", f"`{shown}`"),
        ("exit status", str(outcome.status)),
        ("commit", commit),
        ("build", build),
        ("machine", machine),
        ("load average (1, 5, 15 min)", f"{load_before} before; {load_after} after"),
    ]
    if note:
        rows.append(("note", note))
    fence = "````" if "```" in outcome.output else "```"
    lang = "json" if outcome.output.lstrip().startswith(("{", "[")) else "text"
    lines = [f"# {topic}: {outcome.started:%Y-%m-%d %H:%M} UTC", "",
             "Generated by `scripts/measure.py`: the command's own output, not edited.", "",
             "| | |", "|---|---|", *(f"| {k} | {v} |" for k, v in rows), "",
             *figure_table(outcome.output), "## Output", "", f"{fence}{lang}",
             outcome.output.rstrip("\n"), fence]
    if outcome.left_out_bytes:
        lines += ["", f"({outcome.left_out_bytes} bytes more of output left out.)"]
    return "\n".join(lines) + "\n"


def write_new(folder: Path, day: datetime, topic: str, text: str) -> Path:
    """Write ``text`` to a file of ``folder`` named after the day and the topic that does not
    exist yet (created exclusively: a file already there is never replaced)."""
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"{day:%Y-%m-%d}-{topic}"
    for n in range(1, 1000):
        path = folder / (f"{stem}.md" if n == 1 else f"{stem}-{n}.md")
        try:
            with open(path, "x", encoding="utf-8") as f:
                f.write(text)
        except FileExistsError:
            continue
        return path
    raise MeasureError(f"{folder}: 999 measurements named {stem} already; give --topic")


def command_of(recipe: str, args: Sequence[str]) -> list[str]:
    """The command a recipe runs with the arguments given after it."""
    if recipe not in RECIPES:
        raise MeasureError(f"unknown recipe {recipe!r} (known: {', '.join(RECIPES)})")
    rest = list(args[1:] if args[:1] == ["--"] else args)
    if recipe == "run" and not rest:
        raise MeasureError("run: give the command after --")
    return [*RECIPES[recipe], *rest]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("recipe", help=f"one of {', '.join(RECIPES)}")
    parser.add_argument("--topic", help="the file name's topic (default: the recipe's name)")
    parser.add_argument("--note", default="", help="what else the reader should know")
    parser.add_argument("--out-dir", type=Path, default=ROOT / "measurements")
    parser.add_argument("args", nargs=argparse.REMAINDER, help="arguments of the command")
    options = parser.parse_args(argv)
    try:
        command = command_of(options.recipe, options.args)
        topic = options.topic or options.recipe
        if not TOPIC.fullmatch(topic):
            raise MeasureError(f"--topic {topic!r}: lowercase letters, digits and '-', "
                               "at most 60")
    except MeasureError as exc:
        parser.error(str(exc))
    commit, build, machine, before = commit_line(), build_line(), machine_line(), load_average()
    outcome = run_command(command)
    text = render(topic, command, outcome, commit=commit, build=build, machine=machine,
                  load_before=before, load_after=load_average(), note=options.note)
    path = write_new(options.out_dir, outcome.started, topic, text)
    print(f"measure: {path} (exit status {outcome.status})", file=sys.stderr)
    return outcome.status


if __name__ == "__main__":
    sys.exit(main())
