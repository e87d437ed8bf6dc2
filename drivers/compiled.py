"""Which build of the hot modules runs: the one mypyc compiled at install, or their Python source.

The modules in :data:`COMPILED_MODULES` carry the per-reply work of the emulator and the driver;
``setup.py`` compiles them with mypyc when it can (``docs/performance.md``) and records the SHA-256
of each source it compiled. Python would import an extension module before its ``.py``, so a
compiled module whose source has changed since (an editable install being worked on) would run
the old code. :func:`build` therefore loads the Python source of every one of them when any
source differs from what was compiled, when the build is partial, or when
``ARMBENCH_PURE_PYTHON`` is set: all or none, as compiled modules call each other natively.

This module imports nothing of armbench, so ``setup.py`` reads the list from it before anything
is installed.
"""

from __future__ import annotations

import hashlib
import importlib.abc
import importlib.machinery
import importlib.util
import json
import os
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

__all__ = [
    "COMPILED_MODULES",
    "DIGESTS_FILE",
    "PURE_ENV",
    "build",
    "module_source",
    "pure_requested",
    "source_digest",
    "why_source",
]

#: The hot modules, compiled together as one group.
COMPILED_MODULES = (
    "drivers.protocol",
    "fakes.boards",
    "fakes.i2c",
    "fakes.joint",
    "fakes.uart",
)
#: Set to anything but ``""`` or ``"0"``: build and run the Python source only.
PURE_ENV = "ARMBENCH_PURE_PYTHON"
#: Beside this module: ``{module: SHA-256 of the source compiled}``, written by the build.
DIGESTS_FILE = "_compiled.json"

_ROOT = Path(__file__).resolve().parent.parent
_build: str | None = None


def source_digest(path: Path) -> str:
    """SHA-256 (hex) of a source file's bytes."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


def module_source(name: str, root: Path = _ROOT) -> Path:
    """The ``.py`` file of a module under ``root`` (``fakes.joint`` → ``root/fakes/joint.py``)."""
    return root.joinpath(*name.split(".")).with_suffix(".py")


def _is_compiled(source: Path) -> bool:
    """Whether an extension module lies beside ``source``."""
    return any(source.with_suffix(suffix).exists()
               for suffix in importlib.machinery.EXTENSION_SUFFIXES)


def pure_requested() -> bool:
    """Whether ``ARMBENCH_PURE_PYTHON`` asks for the Python source."""
    return os.environ.get(PURE_ENV, "") not in ("", "0")


def why_source(root: Path = _ROOT, modules: Sequence[str] = COMPILED_MODULES) -> str | None:
    """Why the compiled modules under ``root`` must not run (None: they may), or ``""`` when
    none was compiled."""
    sources = {m: module_source(m, root) for m in modules}
    missing = [m for m, source in sources.items() if not _is_compiled(source)]
    if len(missing) == len(sources):
        return ""
    if pure_requested():
        return f"{PURE_ENV} is set"
    if missing:
        return f"partial build: {', '.join(missing)} not compiled"
    try:
        digests = json.loads((root / "drivers" / DIGESTS_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return f"no record of the compiled sources (drivers/{DIGESTS_FILE})"
    changed = [str(source.relative_to(root)) for m, source in sources.items()
               if digests.get(m) != source_digest(source)]
    if changed:
        return f"{', '.join(changed)} changed since compiled"
    return None


class _SourceFinder(importlib.abc.MetaPathFinder):
    """Finds the listed modules as their ``.py`` files, ahead of the compiled ones."""

    def __init__(self, sources: dict[str, Path]) -> None:
        self.sources = sources

    def find_spec(self, fullname: str, path: Sequence[str] | None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        source = self.sources.get(fullname)
        if source is None:
            return None
        return importlib.util.spec_from_file_location(fullname, source)


def build() -> str:
    """The build running in this process: ``compiled (mypyc)`` or ``source (why)``. Decided at the
    first call, which both packages make before importing any hot module."""
    global _build
    if _build is not None:
        return _build
    reason = why_source()
    if reason is None:
        _build = "compiled (mypyc)"
    elif not reason:
        _build = "source (not compiled)"
    else:
        sys.meta_path.insert(0, _SourceFinder({m: module_source(m) for m in COMPILED_MODULES}))
        if not pure_requested():
            warnings.warn(f"armbench: running the Python source of its compiled modules "
                          f"({reason}); rebuild with `python3 -m pip install -e .` for speed",
                          RuntimeWarning, stacklevel=2)
        _build = f"source ({reason})"
    return _build
