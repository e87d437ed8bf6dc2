"""The scripts of ``scripts/`` as modules, for their tests (``scripts`` is not a package)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

__all__ = ["SCRIPTS", "load_script"]

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def load_script(name: str) -> ModuleType:
    """``scripts/<name>.py``, loaded by path and registered in ``sys.modules`` (as
    ``armbench_script_<name>``: a dataclass looks its module up while being defined), with
    ``scripts/`` on the import path as when the script runs (it may import its neighbours)."""
    if str(SCRIPTS) not in sys.path:
        sys.path.append(str(SCRIPTS))
    spec = importlib.util.spec_from_file_location(f"armbench_script_{name}",
                                                  SCRIPTS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module
