"""Build: the project's metadata is in pyproject.toml; this adds the hot modules compiled by mypyc.

The modules named in ``drivers/compiled.py`` are compiled when mypyc (a build requirement) and a C
compiler are at hand and ``ARMBENCH_PURE_PYTHON`` is not set; otherwise, or if compiling fails,
the package installs as plain Python and runs the same source, slower. Beside the extensions the
build writes ``drivers/_compiled.json``, the SHA-256 of each source compiled, so that the package
can tell a compiled module from one whose source has changed since (see ``docs/performance.md``).
"""

from __future__ import annotations

import json
import runpy
import sys
from pathlib import Path
from typing import Any

from setuptools import setup
from setuptools.command.build_ext import build_ext

ROOT = Path(__file__).resolve().parent
_compiled: dict[str, Any] = runpy.run_path(str(ROOT / "drivers" / "compiled.py"))
MODULES: tuple[str, ...] = _compiled["COMPILED_MODULES"]


def _say(message: str) -> None:
    print(f"armbench build: {message}", file=sys.stderr)


def _extensions() -> list[Any]:
    if _compiled["pure_requested"]():
        _say(f"{_compiled['PURE_ENV']} is set: plain Python, nothing compiled")
        return []
    try:
        from mypyc.build import mypycify
    except ImportError:
        _say("mypyc is not installed: plain Python, nothing compiled")
        return []
    sources = [str(_compiled["module_source"](m, Path(".")).as_posix()) for m in MODULES]
    try:
        extensions: list[Any] = mypycify(sources, opt_level="3")
    except (Exception, SystemExit) as exc:  # mypy reports type errors by exiting
        _say(f"mypyc could not compile {sources} ({exc!r}): plain Python")
        return []
    for ext in extensions:
        ext.optional = True  # no C compiler: skip, and the package runs its Python source
    return extensions


class BuildExt(build_ext):
    """``build_ext`` that records the digests of the sources once every extension is built."""

    def run(self) -> None:
        super().run()
        outputs = [Path(p) for p in self.get_outputs()]
        if not outputs:  # nothing was to be compiled (said above)
            return
        if not all(p.exists() for p in outputs):
            _say("some extensions were not built: the package will run its Python source")
            return
        digests = {m: _compiled["source_digest"](_compiled["module_source"](m, ROOT))
                   for m in MODULES}
        base = ROOT if self.inplace else Path(self.build_lib)
        target = base / "drivers" / _compiled["DIGESTS_FILE"]
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(json.dumps(digests, indent=1, sort_keys=True) + "\n", encoding="utf-8")
        _say(f"compiled {', '.join(MODULES)} with mypyc")


setup(ext_modules=_extensions(), cmdclass={"build_ext": BuildExt})
