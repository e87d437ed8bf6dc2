"""Differential fuzzing of the UART: the firmware in simavr against the emulator, same sessions.

    python fuzz/fuzz_differential.py --seconds 600 --seed 1 --workdir runs/diff
    python fuzz/fuzz_differential.py --sessions 20 --seed 7
    python fuzz/fuzz_differential.py --replay fuzz/corpus/differential   # saved sessions

Each session (``fakes/avr/fuzzer.py``: valid commands, malformed frames, noise, split writes,
bursts, pauses, power cuts; 0.25–0.45 simulated seconds) is played to the emulator on virtual
time and to the firmware in the harness, and the two outcomes are compared
(``fakes/avr/fuzz_session.py``): the commands each master took, exactly, and the replies within the
differential check's tolerances. Sessions reaching new firmware code (the harness's
``--coverage``) join the corpus and are mutated. A divergence is minimised and saved as
``WORKDIR/divergences/<n>.session`` (a harness script; replay it with ``--replay``) with what
differed in ``<n>.txt``; the corpus goes to ``WORKDIR/corpus`` (give it to ``--seeds-from`` to
go on from it) and the firmware lines never reached to ``WORKDIR/lines-not-reached.txt``.
Every ``--report-s`` seconds a progress line: sessions, sessions per second, corpus, features,
firmware lines reached. Exit status 1 if anything diverged.

Not an atheris target: libFuzzer cannot take the firmware's coverage (it lives in the harness
process), so the loop is this file's own; ``fuzz_emulator_uart.py`` covers the emulator alone
under atheris.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from _harness import ROOT

from armbench.fakes.avr.fuzz_session import Session, run_emulator_session, run_firmware_session
from armbench.fakes.avr.fuzz_session import divergences as session_divergences
from armbench.fakes.avr.fuzzer import Campaign, firmware_lines

CORPUS = ROOT / "fuzz" / "corpus" / "differential"


def replay(paths: list[Path]) -> int:
    files = sorted(f for p in paths for f in ([p] if p.is_file() else p.glob("*.session")))
    bad = 0
    for f in files:
        session = Session.from_text(f.read_text())
        found = session_divergences(session, run_emulator_session(session),
                                    run_firmware_session(session))
        print(f"{'DIVERGES' if found else 'ok':<9} {f}")
        for line in found:
            print(f"    {line}")
        bad += bool(found)
    print(f"{len(files)} sessions, {bad} diverging")
    return 1 if bad else 0


def _progress(c: Campaign, every: set[tuple[str, int]] | None) -> dict[str, object]:
    elapsed = time.monotonic() - c.started
    reached, total = firmware_lines(c.pcs) if every is None else (None, every)
    line: dict[str, object] = {
        "elapsed_s": round(elapsed, 1), "sessions": c.sessions,
        "sessions_per_s": round(c.sessions / elapsed, 2) if elapsed else 0.0,
        "corpus": len(c.corpus), "features": len(c.features),
        "diverging_sessions": c.diverging, "divergences": len(c.findings)}
    if reached is not None:
        line["firmware_lines"] = f"{len(reached)}/{len(total)}"
    return line


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--seconds", type=float, default=60.0, help="wall-clock budget")
    parser.add_argument("--sessions", type=int, default=None, help="stop after this many")
    parser.add_argument("--workdir", type=Path, default=Path("runs/fuzz-differential"))
    parser.add_argument("--report-s", type=float, default=60.0)
    parser.add_argument("--seeds-from", type=Path, default=CORPUS,
                        help="sessions run first (default: the committed corpus)")
    parser.add_argument("--replay", type=Path, nargs="+", default=None)
    # libFuzzer's spelling, so fuzz/run_all.py can pass one time budget to every target
    parser.add_argument("-max_total_time", dest="max_total_time", type=float, default=None)
    args, unknown = parser.parse_known_args(argv)
    if args.replay:
        return replay(args.replay)
    seconds = args.max_total_time if args.max_total_time is not None else args.seconds
    if unknown:
        print(f"ignored (libFuzzer flags): {' '.join(unknown)}", file=sys.stderr)
    out = args.workdir / "divergences"
    out.mkdir(parents=True, exist_ok=True)
    corpus_out = args.workdir / "corpus"
    corpus_out.mkdir(exist_ok=True)
    c = Campaign(args.seed)
    seeds = sorted(args.seeds_from.glob("*.session")) if args.seeds_from.is_dir() else []
    queue = [Session.from_text(p.read_text()) for p in seeds]
    next_report = args.report_s
    progress = args.workdir / "progress.jsonl"
    with progress.open("a") as log:
        while time.monotonic() - c.started < seconds and (args.sessions is None
                                                           or c.sessions < args.sessions):
            before, kept = len(c.findings), len(c.corpus)
            c.run_one(queue.pop(0) if queue else None)
            if len(c.corpus) > kept:
                (corpus_out / f"{len(c.corpus)}.session").write_text(c.corpus[-1].to_text())
            for k, finding in enumerate(c.findings[before:], before + 1):
                (out / f"{k}.session").write_text(finding.session.to_text())
                (out / f"{k}.txt").write_text("\n".join(finding.differences) + "\n\noriginal:\n"
                                              + finding.original.to_text())
                print(f"DIVERGENCE {k}: {finding.differences[0]} (minimised: {out}/{k}.session)",
                      flush=True)
            if time.monotonic() - c.started >= next_report:
                next_report = time.monotonic() - c.started + args.report_s
                line = _progress(c, None)
                log.write(json.dumps(line) + "\n")
                log.flush()
                print(json.dumps(line), flush=True)
        final = _progress(c, None)
        final["final"] = True
        final["seed"] = args.seed
        log.write(json.dumps(final) + "\n")
    reached, every = firmware_lines(c.pcs)
    (args.workdir / "lines-not-reached.txt").write_text(
        "".join(f"{name}:{line}\n" for name, line in sorted(every - reached)))
    print(json.dumps(final), flush=True)
    return 1 if c.findings else 0


if __name__ == "__main__":
    sys.exit(main())
