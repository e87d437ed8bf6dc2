"""``armbench config show [--config FILE]``: the config a run is judged with, as TOML.

The effective config of ``armbench run``, ``armbench compare`` and ``armbench campaign``: the
file given with ``--config`` (it replaces the packaged one as a whole), else the packaged
``default_bench.toml``, with every default written out (``regression.default_tolerance_pct``,
``tolerance_abs``). Copy it to start a config of your own.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import tomli_w

from armbench.bench.verdict import DEFAULT_CONFIG, load_config

__all__ = ["register", "render_config"]


def register(sub: Any) -> None:
    """Add the ``config`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "config",
        description="Print the effective bench config (limits, regression tolerances, [bench] "
                    "and [suites.*] parameters) as TOML: --config FILE, else the packaged "
                    "default.",
        epilog="Exit status: 0 printed, 2 the config cannot be read.")
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    show = actions.add_parser("show", help="print the effective config as TOML")
    show.add_argument("--config", metavar="FILE", default=None,
                      help="the config given to armbench run --config (default: the packaged "
                           "default_bench.toml)")
    show.set_defaults(func=_show)


def render_config(path: str | None) -> str:
    """The effective config of ``--config path`` as TOML text, headed by where it came from."""
    config = load_config(path)
    source = path if path is not None else f"{DEFAULT_CONFIG} (packaged default)"
    return (f"# effective armbench config from {source}\n"
            + tomli_w.dumps(config.to_mapping()))


def _show(args: argparse.Namespace) -> int:
    sys.stdout.write(render_config(args.config))
    return 0
