"""The differential fuzzer of the UART: generated sessions on the firmware and the emulator.

:func:`generate` makes a session from a seed: valid commands, malformed frames (a valid frame
with characters replaced, dropped or added, positions above 62832, three-digit duties, the reply
shape), noise (bytes of every value, runs of ``#`` and ``$``, line ends), frames split across
writes with pauses or sent back to back faster than the line, power cuts. :func:`mutate` varies a
session of the corpus. :class:`Campaign` runs them coverage-guided: a session that executes a new
firmware branch edge or instruction (the harness's ``--coverage``) joins the corpus. Each
divergence (``fakes/avr/fuzz_session.py``) is minimised (:func:`minimise`) and saved as a session
file that ``fuzz/fuzz_differential.py --replay`` and the tests replay. Everything is drawn from one
``random.Random(seed)``, so a campaign is replayable from its seed.
"""

from __future__ import annotations

import bisect
import random
import re
import subprocess
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from armbench.drivers.model.protocol import Command, Reply
from armbench.fakes.avr.fuzz_session import (
    BOOT_S,
    BYTE_S,
    Event,
    Outcome,
    Power,
    Session,
    Write,
    divergences,
    run_emulator_session,
    run_firmware_session,
)
from armbench.fakes.avr.harness import find_images

__all__ = ["Campaign", "Finding", "firmware_lines", "generate", "minimise", "mutate",
           "normalise", "signature"]

#: Bytes completing this close to a receiver edge (power cut, the end of the boot) are left out
#: of sessions: the two sides start their receivers some microseconds apart, below what the
#: protocol can promise.
EDGE_S = 1e-3
#: Nor does a frame end this shortly before a power cut: whether a master's loop takes it before
#: the cut depends on its loop phase (a loop each, 2.4 and 3.0 ms, and a record's stall).
CUT_TAKE_S = 0.025
MAX_BYTES = 2048  # per session: well inside the harness's 4 KiB host queue
INTERESTING = b"$#,0123456789\r\n"


def _valid(rng: random.Random) -> bytes:
    q = [rng.uniform(-0.3, 0.3) for _ in range(4)]
    duty = [rng.choice((0, rng.randint(1, 99), 99)) for _ in range(4)]
    return Command.from_rad(q, duty).encode()


def _malformed(rng: random.Random) -> bytes:
    frame = bytearray(_valid(rng))
    for _ in range(rng.randint(1, 3)):
        how = rng.randrange(7)
        i = rng.randrange(len(frame)) if frame else 0
        if how == 0 and frame:  # one character replaced
            frame[i] = rng.choice((rng.choice(INTERESTING), rng.randrange(256),
                                   rng.choice(b"AZaz -+.")))
        elif how == 1 and frame:  # one dropped (a short frame)
            del frame[i]
        elif how == 2:  # one added (a long frame)
            frame.insert(i, rng.choice(INTERESTING))
        elif how == 3:  # a position field out of range, or past 16 bits
            j = rng.randrange(4)
            value = rng.choice((62833, 65535, 65536, 99999, rng.randint(62833, 99999)))
            text = frame.decode("latin-1")
            fields = re.findall(r"\d{5}", text)
            if len(fields) > j:
                frame = bytearray(text.replace(fields[j], f"{value:05d}", 1).encode("latin-1"))
        elif how == 4:  # a three-digit duty
            text = frame.decode("latin-1")
            frame = bytearray(re.sub(r",(\d\d)(?=[,#])", lambda m: f",{m[1]}9", text, count=1)
                              .encode("latin-1"))
        elif how == 5:  # the '#' gone: runs into whatever follows
            frame = frame.replace(b"#", b"")
        else:  # a reply's shape
            frame = bytearray(Reply(*(rng.randint(0, 62832) for _ in range(4))).encode())
    return bytes(frame)


def _noise(rng: random.Random) -> bytes:
    how = rng.randrange(4)
    if how == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randint(1, 256)))
    if how == 1:
        return rng.choice((b"#", b"$", b"$#", b"#$")) * rng.randint(1, 80)
    if how == 2:
        return rng.choice((b"\r\n", b"\n", b"\r")) * rng.randint(1, 4)
    return bytes(range(256))


def _item(rng: random.Random) -> bytes:
    kind = rng.random()
    if kind < 0.4:
        return _valid(rng)
    if kind < 0.75:
        return _malformed(rng)
    return _noise(rng)


def _split(rng: random.Random, at_s: float, data: bytes) -> list[Event]:
    """One item as a single write, or cut into pieces sent back to back (a burst: the line
    queues them) or with pauses between."""
    if len(data) < 2 or rng.random() < 0.6:
        return [Write(at_s, data)]
    cuts = sorted(rng.sample(range(1, len(data)), min(len(data) - 1, rng.randint(1, 4))))
    out: list[Event] = []
    t = at_s
    for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True):
        out.append(Write(round(t, 6), data[a:b]))
        t += rng.choice((0.0, rng.uniform(0, 1e-3), rng.uniform(0, 8e-3)))
    return out


def generate(rng: random.Random) -> Session:
    """A new session: 0.25–0.45 s from power-up, up to eight items, a power cut in one of four."""
    until = round(rng.uniform(0.25, 0.45), 4)
    events: list[Event] = []
    if rng.random() < 0.25:
        off = round(rng.uniform(BOOT_S + 0.02, until - 0.08), 6)
        events += [Power(off, False), Power(round(off + rng.uniform(0.002, 0.06), 6), True)]
    for _ in range(rng.randint(1, 8)):
        at = round(rng.uniform(BOOT_S - 0.01, until - 0.03), 6)
        events += _split(rng, at, _item(rng))
    return normalise(Session(tuple(events), until))


def _receiver_edges(events: list[Event]) -> list[float]:
    """When the master's receiver starts (the end of each boot) or stops (each power cut)."""
    edges = [BOOT_S]
    for e in events:
        if isinstance(e, Power):
            edges.append(e.at_s + BOOT_S if e.on else e.at_s)
    return sorted(edges)


def normalise(session: Session) -> Session:
    """Events in time order, power events alternating off/on from the power-up, at most
    :data:`MAX_BYTES` sent, no byte completing within :data:`EDGE_S` of a receiver edge and no
    '#' within :data:`CUT_TAKE_S` before a power cut."""
    events = sorted(session.events, key=lambda e: e.at_s)
    kept: list[Event] = []
    on = True
    for e in events:
        if isinstance(e, Power):
            if e.on != on and 0 < e.at_s < session.until_s:
                kept.append(e)
                on = e.on
        elif e.data and 0 <= e.at_s < session.until_s:
            kept.append(e)
    edges = _receiver_edges(kept)
    cuts = [e.at_s for e in kept if isinstance(e, Power) and not e.on]
    out: list[Event] = []
    line_free = 0.0
    sent = 0
    for e in kept:
        if isinstance(e, Write):
            start = max(e.at_s, line_free)
            first, last = start + BYTE_S, start + len(e.data) * BYTE_S
            k = bisect.bisect_left(edges, first - EDGE_S)
            if (k < len(edges) and edges[k] <= last + EDGE_S) or sent + len(e.data) > MAX_BYTES:
                continue
            if b"#" in e.data and any(first - EDGE_S <= cut <= last + CUT_TAKE_S for cut in cuts):
                continue
            line_free = start + len(e.data) * BYTE_S
            sent += len(e.data)
        out.append(e)
    return Session(tuple(out), session.until_s)


def mutate(rng: random.Random, session: Session, other: Session | None = None) -> Session:
    """A variation of ``session``: an event added, dropped, moved or its bytes changed, or the
    tail of ``other`` spliced on."""
    events = list(session.events)
    how = rng.randrange(6)
    if how == 0 or not events:
        events += _split(rng, round(rng.uniform(BOOT_S - 0.01, session.until_s - 0.03), 6),
                         _item(rng))
    elif how == 1:
        del events[rng.randrange(len(events))]
    elif how == 2:
        k = rng.randrange(len(events))
        e = events[k]
        t = round(max(0.0, e.at_s + rng.choice((-1, 1)) * rng.choice((BYTE_S, 1e-3, 5e-3))), 6)
        events[k] = Write(t, e.data) if isinstance(e, Write) else Power(t, e.on)
    elif how == 3:
        writes = [k for k, e in enumerate(events) if isinstance(e, Write)]
        if writes:
            k = rng.choice(writes)
            w = events[k]
            assert isinstance(w, Write)
            data = bytearray(w.data)
            i = rng.randrange(len(data))
            data[i] = rng.choice((rng.choice(INTERESTING), rng.randrange(256)))
            events[k] = Write(w.at_s, bytes(data))
    elif how == 4 and other is not None:
        cut = rng.uniform(0, session.until_s)
        events = [e for e in events if e.at_s < cut] + [e for e in other.events if e.at_s >= cut]
    else:
        events.append(Write(round(rng.uniform(BOOT_S, session.until_s - 0.03), 6),
                            _malformed(rng)))
    return normalise(Session(tuple(events), session.until_s))


Runner = Callable[[Session], list[str]]


def check(session: Session) -> list[str]:
    """Run both sides and return their divergences."""
    return divergences(session, run_emulator_session(session), run_firmware_session(session))


def _shrink_writes(session: Session, still: Callable[[Session], bool],
                   budget: list[int]) -> Session:
    events = list(session.events)
    for k in range(len(events)):
        e = events[k]
        if not isinstance(e, Write):
            continue
        step = len(e.data) // 2
        while step >= 1 and budget[0] > 0:
            data = events[k].data  # type: ignore[union-attr]
            shrunk = False
            for i in range(0, len(data), step):
                trial = data[:i] + data[i + step:]
                if not trial:
                    continue
                budget[0] -= 1
                candidate = [*events[:k], Write(e.at_s, trial), *events[k + 1:]]
                if still(Session(tuple(candidate), session.until_s)):
                    events = candidate
                    shrunk = True
                    break
                if budget[0] <= 0:
                    break
            if not shrunk:
                step //= 2
    return Session(tuple(events), session.until_s)


def minimise(session: Session, runner: Runner = check, budget: int = 80) -> Session:
    """A smaller session that still diverges: events dropped one by one, then the bytes of each
    write halved and cut, the session shortened; at most ``budget`` runs."""
    left = [budget]

    def still(candidate: Session) -> bool:
        return bool(runner(normalise(candidate)))

    events = list(session.events)
    k = 0
    while k < len(events) and left[0] > 0:
        candidate = events[:k] + events[k + 1:]
        left[0] -= 1
        if still(Session(tuple(candidate), session.until_s)):
            events = candidate
        else:
            k += 1
    shrunk = _shrink_writes(Session(tuple(events), session.until_s), still, left)
    last = max((e.at_s for e in shrunk.events), default=0.0)
    for until in (last + 0.05, last + 0.1):
        if until < shrunk.until_s and left[0] > 0:
            left[0] -= 1
            if still(Session(shrunk.events, round(until, 4))):
                shrunk = Session(shrunk.events, round(until, 4))
                break
    return normalise(shrunk)


def signature(differences: list[str]) -> str:
    """What kind of divergence: the first difference with its numbers blanked."""
    return re.sub(r"[\d.]+", "#", differences[0]) if differences else ""


@dataclass
class Finding:
    """A divergence: the minimised session and what differed."""

    session: Session
    differences: list[str]
    original: Session


@dataclass
class Campaign:
    """A seeded, coverage-guided run of generated and mutated sessions."""

    seed: int
    corpus: list[Session] = field(default_factory=list)
    features: set[tuple[int, int]] = field(default_factory=set)
    pcs: dict[int, set[int]] = field(default_factory=dict)
    findings: list[Finding] = field(default_factory=list)
    sessions: int = 0
    diverging: int = 0
    """Sessions that diverged (findings keep the first of each :func:`signature`)."""
    kinds: set[str] = field(default_factory=set)
    started: float = field(default_factory=time.monotonic)

    def __post_init__(self) -> None:
        self.rng = random.Random(self.seed)

    def next_session(self) -> Session:
        if not self.corpus or self.rng.random() < 0.4:
            return generate(self.rng)
        other = self.rng.choice(self.corpus)
        return mutate(self.rng, self.rng.choice(self.corpus), other)

    def run_one(self, session: Session | None = None, minimise_budget: int = 80) -> list[str]:
        """Run one session (the next one drawn when None); keep it if it reached new firmware
        code; minimise and record a divergence."""
        session = session if session is not None else self.next_session()
        emu = run_emulator_session(session)
        fw = run_firmware_session(session, coverage=True)
        self.sessions += 1
        if self._learn(fw):
            self.corpus.append(session)
        found = divergences(session, emu, fw)
        if found:
            self.diverging += 1
            kind = signature(found)
            if kind not in self.kinds:  # one bug found a hundred times is one finding
                self.kinds.add(kind)
                small = minimise(session, budget=minimise_budget)
                self.findings.append(Finding(small, check(small) or found, session))
        return found

    def _learn(self, fw: Outcome) -> bool:
        new = {(0, e) for e in fw.edges} | {(j, pc) for j, pcs in fw.pcs.items() for pc in pcs}
        for j, pcs in fw.pcs.items():
            self.pcs.setdefault(j, set()).update(pcs)
        fresh = new - self.features
        self.features |= fresh
        return bool(fresh)


def _line_table(image: Path) -> dict[int, tuple[str, int]]:
    """Flash byte address -> (source file name, line) of an ELF image, for ``firmware/*.c``."""
    size = subprocess.run(["avr-size", "-A", str(image)], capture_output=True, text=True,
                          check=True).stdout
    m = re.search(r"^\.text\s+(\d+)", size, re.MULTILINE)
    text_bytes = int(m.group(1)) if m else 0
    addresses = list(range(0, text_bytes, 2))
    out = subprocess.run(["avr-addr2line", "-e", str(image)],
                         input="\n".join(f"{a:#x}" for a in addresses), capture_output=True,
                         text=True, check=True).stdout.splitlines()
    table = {}
    for address, where in zip(addresses, out, strict=False):
        path, _, line = where.rpartition(":")
        digits = line.split()[0] if line else ""
        if Path(path).parent.name == "firmware" and path.endswith(".c") and digits.isdigit():
            table[address] = (Path(path).name, int(digits))
    return table


Lines = set[tuple[str, int]]


def firmware_lines(pcs: dict[int, set[int]], firmware: str | None = None) -> tuple[Lines, Lines]:
    """Lines of ``firmware/*.c`` reached by the executed addresses ``pcs`` (per joint 1..4), and
    all lines that hold code, over the four images."""
    reached: Lines = set()
    every: Lines = set()
    for joint, image in enumerate(find_images(firmware), 1):
        table = _line_table(image)
        every |= set(table.values())
        reached |= {table[pc] for pc in pcs.get(joint, ()) if pc in table}
    return reached, every
