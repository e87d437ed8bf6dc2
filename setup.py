"""Build: the project's metadata is in pyproject.toml; this adds the hot modules compiled by mypyc.

A regular (wheel) build compiles the modules named in ``armbench/hot_modules.py`` when mypyc (a
build requirement) and a C compiler are at hand, as black's release wheels are built: each compiled
module sits beside its source in the installed package and Python imports it first. Nothing chooses
a build at import time. An editable install never compiles (it runs the source being edited), and
``ARMBENCH_PURE_PYTHON=1`` at build time installs plain Python; see ``docs/performance.md``.
"""

from __future__ import annotations

import os
import runpy
import sys
from pathlib import Path
from typing import Any

from setuptools import setup

ROOT = Path(__file__).resolve().parent
HOT_MODULES: tuple[str, ...] = runpy.run_path(str(ROOT / "armbench" / "hot_modules.py"))[
    "HOT_MODULES"]
PURE_ENV = "ARMBENCH_PURE_PYTHON"
#: mypyc's shared library of the group, inside the package: ``armbench/hot__mypyc.*.so``.
GROUP = "armbench.hot"
#: setup.py commands that build a wheel or extensions; metadata and editable builds compile nothing.
_BUILDING = {"bdist_wheel", "build", "build_ext", "install"}


def _say(message: str) -> None:
    print(f"armbench build: {message}", file=sys.stderr)


def _extensions() -> list[Any]:
    if not _BUILDING & set(sys.argv[1:]):
        return []
    if os.environ.get(PURE_ENV, "") not in ("", "0"):
        _say(f"{PURE_ENV} is set: plain Python, nothing compiled")
        return []
    try:
        from mypyc.build import mypycify
    except ImportError:
        _say("mypyc is not installed: plain Python, nothing compiled")
        return []
    sources = [m.replace(".", "/") + ".py" for m in HOT_MODULES]
    try:
        extensions: list[Any] = mypycify(sources, opt_level="3", group_name=GROUP)
    except (Exception, SystemExit) as exc:  # mypy reports type errors by exiting
        _say(f"mypyc could not compile {sources} ({exc!r}): plain Python")
        return []
    for ext in extensions:
        ext.optional = True  # no C compiler: the package runs its Python source
    _say(f"compiling {', '.join(HOT_MODULES)} with mypyc")
    return extensions


setup(ext_modules=_extensions())
