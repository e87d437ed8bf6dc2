"""Build: the project's metadata is in pyproject.toml; this maps the folders to the package and adds
the hot modules compiled by mypyc.

The checkout keeps its packages at the top, one folder each (``SUBPACKAGES``: ``cli/``,
``frontends/``, ``reports/``, ``bench/``, ``record/``, ``metrics/``, ``fakes/``, ``drivers/``; their
layers are in ``docs/architecture.md``). They install as one namespace, ``armbench`` (``api/``
holds the package's own modules: the public API, ``python -m armbench`` and the list of compiled
modules), through setuptools' ``package_dir`` mapping, and the firmware sources (``firmware/``)
install beside them as ``armbench/firmware``, so ``armbench firmware build`` and ``avr://`` work
from a regular install. No folder of the checkout is named ``armbench``: from the checkout, as
from anywhere, ``import armbench`` finds the installed build (the compiled wheel, the
plain-Python one or an editable install), never a second copy of the source
(``docs/performance.md``).

A regular (wheel) build compiles the modules named in ``cli/perf/hot_modules.py`` when mypyc (a
build requirement) and a C compiler are at hand, as black's release wheels are built: each compiled
module sits beside its source in the installed package and Python imports it first. mypyc names a
module by its path, so it compiles a staged copy of the package laid out as it installs
(``build/mypyc-stage/armbench/...``). An editable install never compiles (it runs the source being
edited), and ``ARMBENCH_PURE_PYTHON=1`` at build time installs plain Python.
"""

from __future__ import annotations

import os
import runpy
import shutil
import sys
from pathlib import Path
from typing import Any

from setuptools import find_namespace_packages, setup

ROOT = Path(__file__).resolve().parent
#: Each installed package and the checkout folder it comes from.
SUBPACKAGES = ("bench", "cli", "drivers", "fakes", "frontends", "metrics", "record", "reports")
PACKAGE_DIR = {"armbench": "api", "armbench.firmware": "firmware",
               **{f"armbench.{name}": name for name in SUBPACKAGES}}
PACKAGES = ["armbench", "armbench.firmware",
            *(f"armbench.{name}" for name in find_namespace_packages(
                where=str(ROOT), include=[*SUBPACKAGES, *(f"{n}.*" for n in SUBPACKAGES)],
                exclude=["*.__pycache__"]))]
#: Data installed with the code: configs, templates, the ROS message definitions the ROS 2 front
#: end builds (with their licences), and the firmware's C sources and Makefile.
PACKAGE_DATA = {"": ["*.toml", "*.j2", "*.html", "*.css", "py.typed", "*.msg", "*.action", "*.srv",
                     "LICENSE"],
                "armbench.firmware": ["Makefile", "*.c", "*.h", "harness/*.c", "harness/*.h"]}
HOT_MODULES: tuple[str, ...] = runpy.run_path(str(ROOT / "cli" / "perf" / "hot_modules.py"))[
    "HOT_MODULES"]
PURE_ENV = "ARMBENCH_PURE_PYTHON"
#: mypyc's shared library of the group, inside the package: ``armbench/hot__mypyc.*.so``.
GROUP = "armbench.hot"
#: setup.py commands that build a wheel or extensions; metadata and editable builds compile nothing.
_BUILDING = {"bdist_wheel", "build", "build_ext", "install"}


def _say(message: str) -> None:
    print(f"armbench build: {message}", file=sys.stderr)


def stage_package(dest: Path) -> Path:
    """Copy the package's Python sources into ``dest/armbench/...`` laid out as they install, for
    tools that name a module by its path (mypyc); returns ``dest``."""
    shutil.rmtree(dest, ignore_errors=True)
    for package, folder in PACKAGE_DIR.items():
        if package == "armbench.firmware":
            continue
        target = dest.joinpath(*package.split("."))
        if package == "armbench":
            target.mkdir(parents=True, exist_ok=True)
            for source in (ROOT / folder).iterdir():
                if source.is_file():
                    shutil.copy2(source, target / source.name)
        else:
            shutil.copytree(ROOT / folder, target, dirs_exist_ok=True,
                            ignore=shutil.ignore_patterns("__pycache__", "*.so", "*.pyd"))
    return dest


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
    stage = stage_package(ROOT / "build" / "mypyc-stage")
    # paths from the checkout: mypy names each module by the packages above it (armbench...)
    sources = [os.path.relpath(stage / (m.replace(".", "/") + ".py"), ROOT) for m in HOT_MODULES]
    try:
        extensions: list[Any] = mypycify(sources, opt_level="3", group_name=GROUP)
    except (Exception, SystemExit) as exc:  # mypy reports type errors by exiting
        _say(f"mypyc could not compile {sources} ({exc!r}): plain Python")
        return []
    for ext in extensions:
        ext.optional = True  # no C compiler: the package runs its Python source
    _say(f"compiling {', '.join(HOT_MODULES)} with mypyc")
    return extensions


setup(packages=PACKAGES, package_dir=PACKAGE_DIR, package_data=PACKAGE_DATA,
      ext_modules=_extensions())
