"""``armbench config show [SUITE ...] [--config FILE] [run flags]``: the effective configuration
of a run, as TOML, each value with where it came from.

What ``armbench run`` with the same arguments would use (its own planning,
``armbench.bench.runner.prepare``, resolves it, so the two cannot disagree): the limits and
regression tolerances of ``--config`` (it replaces the packaged ``default_bench.toml`` as a
whole), else of the packaged file; every ``[bench]`` parameter, from the command line's flag, else
the config file, else the bench's default; every parameter of each suite, from the file's
``[suites.<name>]`` table, else the suite's default; the unit under test's ``[dut]`` keys, from
``--dut`` or ``--meta``, else the file. ``armbench compare`` and ``armbench campaign``
judge with the same limits and tolerances. The output reads back as a ``--config`` file: a run given
it plans the same (the ``[bench]`` defaults that depend on the port, ``isolation``, are the
port's).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import tomli_w

from armbench.bench.runner import RunOptions, prepare
from armbench.bench.runner.power import DEFAULT_COMMAND_TIMEOUT_S
from armbench.cli.commands.bounds import CAPTURE_MAX_MB, add_bounded
from armbench.cli.commands.run import add_dut_arguments
from armbench.drivers.model.settings import read_toml
from armbench.record.dut import Dut, dut_flags
from armbench.record.verdict import DEFAULT_CONFIG

__all__ = ["register", "render_config"]

#: The ``[bench]`` keys a flag of ``armbench run`` overrides, and that flag.
_FLAGS = {"retries": "--retries", "workers": "--workers", "capture": "--no-capture",
          "capture_max_bytes": "--capture-max-mb", "scheduler": "--scheduler"}


def register(sub: Any) -> None:
    """Add the ``config`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "config",
        description="Print the effective configuration of a run (limits, regression "
                    "tolerances, [bench] and [suites.*] parameters) as TOML: defaults, then "
                    "--config FILE, then the flags, each value's origin in a comment.",
        epilog="Exit status: 0 printed, 2 the config (or a flag) cannot be used.")
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    show = actions.add_parser(
        "show", help="print the effective configuration as TOML",
        description="Print what armbench run with these arguments would use, as TOML.")
    show.add_argument("suites", nargs="*", metavar="SUITE",
                      help="the suites of the run (default: every registered suite)")
    show.add_argument("--config", metavar="FILE", default=None,
                      help="the config given to armbench run --config (default: the packaged "
                           "default_bench.toml)")
    show.add_argument("--port", metavar="PORT", default=None,
                      help="the arm's port (default fake://): the [bench] defaults depend on it")
    show.add_argument("--settings", metavar="FILE", help="robot settings TOML")
    show.add_argument("--workers", type=int, default=None, metavar="N")
    show.add_argument("--scheduler", metavar="tcp://HOST:PORT", default=None)
    show.add_argument("--retries", type=int, default=None, metavar="N")
    show.add_argument("--no-capture", dest="capture", action="store_false", default=None)
    add_bounded(show, "--capture-max-mb", CAPTURE_MAX_MB, default=None, metavar="MB")
    add_dut_arguments(show)
    show.set_defaults(func=_show)


def _value(value: object) -> str:
    """A TOML value on one line (tomli_w writes each scalar; arrays inline)."""
    if isinstance(value, list | tuple) and not any(isinstance(v, Mapping) for v in value):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    return tomli_w.dumps({"v": value}).split(" = ", 1)[1].rstrip()


def _line(key: str, value: object, origin: str = "") -> str:
    """``key = value  # origin``: one TOML key-value pair."""
    return f"{_quote(key)} = {_value(value)}" + (f"  # {origin}" if origin else "")


def _table(header: str, values: Mapping[str, Any], origin_of: Mapping[str, str],
           comment: str = "") -> list[str]:
    """A TOML table of plain values (``None`` left out: TOML has none) with their origins; a
    nested table follows as ``[header.key]``."""
    lines = [f"[{header}]" + (f"  # {comment}" if comment else "")]
    nested = []
    for key, value in values.items():
        if value is None:
            continue
        if isinstance(value, Mapping):
            nested.append((key, value))
        else:
            lines.append(_line(key, value, origin_of.get(key, "")))
    for key, value in nested:
        lines += ["", *_table(f"{header}.{_quote(key)}", value, {},
                              origin_of.get(key, ""))]
    return lines


def _quote(key: str) -> str:
    """A TOML key: bare when it can be, else quoted."""
    return key if key.replace("_", "").replace("-", "").isalnum() else tomli_w.dumps(
        {key: 0}).split(" = ")[0]


def render_config(options: RunOptions) -> str:
    """The effective configuration of a run with ``options`` as TOML text, each value's origin
    in a comment. Raises what :func:`~armbench.bench.runner.prepare` raises for a bad input."""
    # nothing is created: prepare only checks that the run folder is writable
    plan = prepare(dataclasses.replace(options, runs_root=tempfile.gettempdir()))
    path = Path(options.config) if options.config is not None else DEFAULT_CONFIG
    source = str(options.config) if options.config is not None else "packaged default"
    raw = read_toml(path, "limits file")
    config = plan.config
    file_bench = config.bench_params()

    def bench_origin(key: str) -> str:
        flag = _FLAGS.get(key)
        value = getattr(options, {"capture_max_bytes": "capture_max_mb"}.get(key, key), None)
        if flag is not None and value is not None:
            return flag
        return source if key in file_bench else "default"

    bench: dict[str, Any] = {
        "retries": plan.retries, "workers": plan.workers, "isolation": plan.isolation,
        "reply_timeout_s": plan.reply_timeout_s, "connect_timeout_s": plan.connect_timeout_s,
        "outage_timeout_s": plan.outage_timeout_s, "settle_s": plan.settle_s,
        "move_timeout_scale": plan.move_timeout_scale,
        "power_timeout_s": float(file_bench.get("power_timeout_s",
                                                DEFAULT_COMMAND_TIMEOUT_S)),
        "capture": plan.capture,
        "capture_max_bytes": plan.capture_max_bytes, "scheduler": plan.scheduler,
    }
    if "tracker" in file_bench:
        bench["tracker"] = file_bench["tracker"]
    lines = [f"# effective armbench config: defaults, then {source} "
             f"({path.resolve()}), then the command line",
             "# each value's origin in its comment; this file given to --config plans the same run",
             _line("spec_version", config.spec_version, source), "",
             *_table("bench", bench, {k: bench_origin(k) for k in bench})]
    regression = raw.get("regression", {})
    lines += ["", "[regression]",
              _line("default_tolerance_pct", config.default_tolerance_pct,
                    source if "default_tolerance_pct" in regression else "default")]
    for name, t in config.tolerances.items():
        lines += ["", *_table(f"regression.metrics.{_quote(name)}",
                              {"tolerance_pct": t.tolerance_pct,
                               "tolerance_abs": t.tolerance_abs}, {}, source)]
    if plan.dut:
        lines += ["", *_dut_table(plan.dut, options, source)]
    for name, limit in config.limits.items():
        lines += ["", *_table(f"limits.{_quote(name)}",
                              {"low": limit.low, "high": limit.high, "unit": limit.unit}, {},
                              source)]
    for planned in plan.suites:
        configured = config.suite_params(planned.ref if planned.ref in config.suites
                                         else planned.suite.name)
        lines += ["", *_table(f"suites.{_quote(planned.suite.name)}", planned.params,
                              {k: source if k in configured else "suite default"
                               for k in planned.params})]
    return "\n".join(lines) + "\n"


def _dut_table(dut: Dut, options: RunOptions, source: str) -> list[str]:
    """The ``[dut]`` table of the run, each value with its origin: ``--dut``, ``--meta`` or
    the config file."""
    flags = dut_flags(options.dut, options.meta)

    def origin(key: str) -> str:
        if key not in flags:
            return source
        return "--dut" if key == "name" and options.dut is not None else "--meta"

    named = {k: v for k, v in dut.items() if not k.startswith("meta.")}
    meta = {k[5:]: v for k, v in dut.items() if k.startswith("meta.")}
    lines = _table("dut", named, {k: origin(k) for k in named})
    if meta:
        lines += ["", *_table("dut.meta", meta, {k: origin(f"meta.{k}") for k in meta})]
    return lines


def _show(args: argparse.Namespace) -> int:
    options = RunOptions(suites=list(args.suites), ports=[] if args.port is None else [args.port],
                         config=args.config, settings=args.settings, workers=args.workers,
                         scheduler=args.scheduler, retries=args.retries, capture=args.capture,
                         capture_max_mb=args.capture_max_mb, dut=args.dut,
                         meta=tuple(args.meta))
    sys.stdout.write(render_config(options))
    return 0
