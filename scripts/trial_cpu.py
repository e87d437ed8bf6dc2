"""The trials' CPU seconds in the workers for one ``armbench run``: the numerator of ``armbench
perf``'s ``run.trials_per_bare_emulator``, compared between variants (another build's
interpreter, other ``armbench run`` options) in fresh processes, taken in turn, so that the bare
emulator, the same for all, cancels out and a slow minute of the machine falls on every variant.

    python scripts/trial_cpu.py [--repeats 3] "NAME=PYTHON [OPTIONS...]" ...

Each variant is one shell-quoted string: its name, the interpreter whose installed armbench runs
(a venv's ``bin/python``) and the ``armbench run`` options, if any (none: the default run).
Prints a line per run (jobs, robot seconds, the trials' CPU seconds summed over the workers) and,
per variant, the least and the mean.
"""

from __future__ import annotations

import argparse
import json
import runpy
import shlex
import statistics
import sys

from child_figures import child_figures


def child(out_dir: str, options: list[str]) -> None:
    """One run in this process (the workers its own), its trial jobs printed as one JSON line
    when the program ends (``armbench run`` ends its process)."""
    import atexit

    from armbench.cli.perf import run_perf

    jobs = run_perf._trial_jobs()  # every job's CPU seconds in its worker, as perf counts them

    def report() -> None:
        print(json.dumps({"jobs": len(jobs), "cpu_s": sum(j["cpu_s"] for j in jobs),
                          "robot_s": sum(j["robot_s"] for j in jobs)}), flush=True)

    atexit.register(report)
    sys.argv = ["armbench", "run", "-q", "--out", out_dir, *options]
    runpy.run_module("armbench", run_name="__main__", alter_sys=True)


def variant(text: str) -> tuple[str, str, list[str]]:
    """``"NAME=PYTHON [OPTIONS...]"`` as (name, interpreter, options)."""
    words = shlex.split(text)
    name, sep, python = words[0].partition("=") if words else ("", "", "")
    if not (sep and name and python):
        raise argparse.ArgumentTypeError(f"{text!r} is not NAME=PYTHON [OPTIONS...]")
    return name, python, words[1:]


def one_run(python: str, options: list[str]) -> dict[str, float]:
    """The trial jobs' figures of one run of ``python``'s armbench with ``options``."""
    result: dict[str, float] = child_figures(python, __file__, options, timeout_s=900)
    return result


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if args[:1] == ["--child"]:
        child(args[1], args[2:])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs of each variant")
    parser.add_argument("variants", nargs="+", type=variant, metavar="NAME=PYTHON [OPTIONS...]")
    ns = parser.parse_args(args)
    cpu: dict[str, list[float]] = {name: [] for name, _, _ in ns.variants}
    for k in range(ns.repeats):
        for name, python, options in ns.variants:
            r = one_run(python, options)
            cpu[name].append(r["cpu_s"])
            print(f"run {k + 1} {name}: {r['jobs']} jobs, {r['robot_s']:.1f} s of robot time, "
                  f"trials' CPU {r['cpu_s']:.3f} s", flush=True)
    for name, values in cpu.items():
        print(f"{name}: least {min(values):.3f} s, mean {statistics.mean(values):.3f} s "
              f"over {len(values)} runs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
