"""The SVGs of the plots drawn already, by what was drawn: a page drawn again from the same
plots draws none of them twice.

The run draws each suite's plots while the next suite's trials go on
(:func:`armbench.reports.pages.page.draw_ahead`); the report written when the run ends then
finds them here. A plot is known by its plot function, the inputs it was called with (their
pickle: equal bytes, equal inputs) and its label, never by the page it is on (a plot function
that its name does not find, a lambda or a closure, is drawn each time); its SVG is kept
with the placeholder id prefix :data:`PLACEHOLDER` and renamed for each page (:func:`renamed`),
so a page is the same text whether its plots were drawn now or before. At most
:data:`MAX_DRAWN` SVGs are kept (the oldest used goes first); a plot whose inputs cannot be
pickled is drawn each time.
"""

from __future__ import annotations

import collections
import gc
import hashlib
import pickle
import re
import sys
import threading
from collections.abc import Callable

from matplotlib.figure import Figure

from armbench.reports.render.plotting import to_svg

__all__ = ["MAX_DRAWN", "PLACEHOLDER", "clear", "drawn", "misses", "renamed"]

MAX_DRAWN = 32
"""Most SVGs kept (a report has about ten plots)."""
PLACEHOLDER = "f0"
"""The id prefix of a kept SVG (a page's plots are numbered from 1)."""

_drawn: collections.OrderedDict[bytes, str] = collections.OrderedDict()
_lock = threading.Lock()
_misses = 0
_PREFIXED = re.compile(r'(id="|href="#|url\(#)f\d+-')


def _named(plot: Callable[..., Figure]) -> bool:
    """Whether ``plot`` is what its module and qualified name find (not a lambda or a closure,
    which a name does not tell apart)."""
    found: object = sys.modules.get(plot.__module__)
    for part in plot.__qualname__.split("."):
        found = getattr(found, part, None)
    return found is plot


def _key(plot: Callable[..., Figure], args: tuple[object, ...], label: str) -> bytes | None:
    if not _named(plot):
        return None
    try:
        data = pickle.dumps((plot.__module__, plot.__qualname__, args, label), protocol=5)
    except Exception:  # an input that cannot be pickled: drawn every time
        return None
    return hashlib.sha256(data).digest()


def drawn(plot: Callable[..., Figure], args: tuple[object, ...], label: str, *,
          collect: bool = True) -> str:
    """The SVG of ``plot(*args)`` labelled ``label`` (:func:`~armbench.reports.render.plotting.
    to_svg`), ids prefixed with :data:`PLACEHOLDER`: drawn now unless it is kept. A figure drawn
    now is freed at once; with ``collect``, the collector runs too (a drawn figure is a web of
    reference cycles; the page sets what existed before it aside, so that is cheap)."""
    global _misses
    key = _key(plot, args, label)
    if key is not None:
        with _lock:
            svg = _drawn.get(key)
            if svg is not None:
                _drawn.move_to_end(key)
                return svg
    fig = plot(*args)
    svg = str(to_svg(fig, PLACEHOLDER, label))
    fig.clear()
    del fig
    if collect:
        gc.collect()
    with _lock:
        _misses += 1
        if key is not None:
            _drawn[key] = svg
            while len(_drawn) > MAX_DRAWN:
                _drawn.popitem(last=False)
    return svg


def renamed(svg: str, number: int) -> str:
    """``svg`` (a kept one, or a plot already on a page) with its ids prefixed for plot
    ``number`` of a page."""
    return _PREFIXED.sub(rf"\g<1>f{number}-", svg)


def misses() -> int:
    """Plots drawn so far (not found kept) in this process."""
    return _misses


def clear() -> None:
    """Forget every kept SVG."""
    with _lock:
        _drawn.clear()
