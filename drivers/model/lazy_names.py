"""Names a package exports but loads on first use (its module's ``__getattr__``, PEP 562): the
package imports cheaply, and a name's module is imported when the name is first read."""

from __future__ import annotations

from collections.abc import Mapping
from importlib import import_module

__all__ = ["lazy_name"]


def lazy_name(package: str, modules: Mapping[str, str], name: str) -> object:
    """``name`` of ``package``, from the module ``modules`` maps it to (imported now);
    :class:`AttributeError`, as for any missing attribute, for a name the package does not
    export."""
    module = modules.get(name)
    if module is None:
        raise AttributeError(f"module {package!r} has no attribute {name!r}")
    return getattr(import_module(module), name)
