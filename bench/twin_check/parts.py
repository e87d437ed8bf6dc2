"""The parts of a capture twin-check judges one by one: a twin must be within its allowance on
every part, not only on the whole (a twin that diverges for a few seconds of a long capture
hides in its whole RMS).

The compared replies are cut into consecutive parts, each beginning at a command (or at the
capture's first compared reply) and spanning at least :data:`PART_S` of the capture's clock; the
last part takes what is left when that is shorter. Per part and joint: the RMS divergence, the
floor over the part's replies (the same parts as the whole's floor: the replies' timing, the
starts' uncertainty, the quantisation, and the reaction replays' divergence over the part), and
the allowance ``k × floor + abs`` of the whole.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

__all__ = ["PART_S", "Part", "cut_parts", "part_figures"]

FloatArray = npt.NDArray[np.float64]

#: A part spans at least this much of the capture's clock (s): several moves of a suite, long
#: enough that its floor is an RMS over many replies.
PART_S: Final = 5.0


@dataclass(frozen=True, slots=True)
class Part:
    """One part: its span (s, capture clock), the number of compared replies, and per joint its
    RMS divergence, floor and allowance (counts)."""

    start_s: float
    end_s: float
    replies: int
    rms_counts: tuple[float, ...]
    floor_counts: tuple[float, ...]
    allowed_counts: tuple[float, ...]

    def per_allowed(self, j: int) -> float:
        """Joint ``j``'s (0-based) RMS over its allowance."""
        return self.rms_counts[j] / self.allowed_counts[j]

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` object."""
        return {"span_s": [self.start_s, self.end_s], "replies": self.replies,
                "rms_counts": list(self.rms_counts), "floor_counts": list(self.floor_counts),
                "allowed_counts": list(self.allowed_counts)}


def cut_parts(t_s: FloatArray, command_times: Sequence[float]) -> list[tuple[int, int]]:
    """The compared replies (times ``t_s``) as index ranges ``[a, b)``, each beginning at a
    command's time (or the first reply) and spanning at least :data:`PART_S`; a last range
    shorter than that joins the one before."""
    if not len(t_s):
        return []
    starts = np.unique(np.searchsorted(t_s, np.asarray(command_times, dtype=np.float64)))
    edges = [0]
    for i in (int(k) for k in starts):
        if 0 < i < len(t_s) and t_s[i] - t_s[edges[-1]] >= PART_S:
            edges.append(i)
    if len(edges) > 1 and t_s[-1] - t_s[edges[-1]] < PART_S:
        edges.pop()
    return list(itertools.pairwise([*edges, len(t_s)]))


def part_figures(t_s: FloatArray, diff_rad: FloatArray, floor2_rad2: FloatArray,
                 counts_per_rad: FloatArray, allowance: tuple[float, float],
                 command_times: Sequence[float],
                 replay: tuple[FloatArray, FloatArray] | None = None) -> list[Part]:
    """Per part (:func:`cut_parts`) of the compared replies (times ``t_s``; arm minus twin and
    the floor's per-reply square, ``(n, 4)``): its figures, allowed ``k × floor + abs``
    (``allowance``: ``(k, abs)``, counts). ``replay``: the reaction replays' times and squared
    divergences (``(m, 4)``), whose mean over the part's span joins its floor (over the whole
    replay where no replay reply falls in the part)."""
    out = []
    for a, b in cut_parts(t_s, command_times):
        d = diff_rad[a:b]
        f2 = np.mean(floor2_rad2[a:b], axis=0)
        if replay is not None and len(replay[0]):
            inside = (replay[0] >= t_s[a]) & (replay[0] <= t_s[b - 1])
            f2 = f2 + np.mean(replay[1][inside] if inside.any() else replay[1], axis=0)
        rms = np.sqrt(np.mean(d * d, axis=0)) * counts_per_rad
        floor = np.sqrt(f2) * counts_per_rad
        allowed = allowance[0] * floor + allowance[1]
        out.append(Part(float(t_s[a]), float(t_s[b - 1]), b - a,
                        tuple(float(v) for v in rms), tuple(float(v) for v in floor),
                        tuple(float(v) for v in allowed)))
    return out
