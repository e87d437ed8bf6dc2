"""Plumbing shared by the atheris harnesses in this folder (not a harness itself).

* adds the target's dictionary (``fuzz/dicts/<target>.dict``) unless ``-dict=`` is given;
* crash *signatures* (``ExceptionType@file:line`` of the innermost frame in the checkout), so one
  bug found ten thousand times is still one bug;
* a keep-going mode for long campaigns: with ``ARMBENCH_FUZZ_KEEP_GOING=DIR`` an exception does not
  stop the fuzzer; the first input of each new signature is saved as ``DIR/<target>/<sig>.bin``
  with its traceback beside it (``.txt``), and fuzzing goes on to find the next bug. Without the
  variable (``tox -e fuzz``, CI) the first exception crashes the run, as libFuzzer expects.
"""

from __future__ import annotations

import os
import re
import sys
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FUZZ_DIR = ROOT / "fuzz"

KEEP_GOING_ENV = "ARMBENCH_FUZZ_KEEP_GOING"

TestOneInput = Callable[[bytes], None]


def split(stream: bytes, sizes: Sequence[int]) -> list[bytes]:
    """``stream`` cut into pieces of ``sizes`` (used cyclically); one piece when ``sizes`` is
    empty."""
    if not sizes:
        return [stream]
    out = []
    pos = 0
    k = 0
    while pos < len(stream):
        size = sizes[k % len(sizes)]
        out.append(stream[pos:pos + size])
        pos += size
        k += 1
    return out


def signature(exc: BaseException) -> str:
    """``Type@path:line`` of the innermost traceback frame inside the checkout."""
    frames = traceback.extract_tb(exc.__traceback__)
    for frame in reversed(frames):
        path = Path(frame.filename)
        if not path.is_absolute():  # e.g. numpy's "numpy/random/bit_generator.pyx"
            continue
        try:
            rel = path.resolve().relative_to(ROOT)
        except ValueError:
            continue
        return f"{type(exc).__name__}@{rel.as_posix()}:{frame.lineno}"
    return f"{type(exc).__name__}@outside-the-checkout"


def _keep_going(target: str, test: TestOneInput, out_dir: Path) -> TestOneInput:
    seen: set[str] = set()
    out = out_dir / target
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("*.bin"):
        seen.add(old.stem)

    def wrapped(data: bytes) -> None:
        try:
            test(data)
        except Exception as exc:  # every exception is a finding here
            sig = signature(exc)
            name = re.sub(r"[^A-Za-z0-9_.@-]+", "_", sig)
            if name in seen:
                return
            seen.add(name)
            (out / f"{name}.bin").write_bytes(data)
            (out / f"{name}.txt").write_text(
                f"{sig}\ninput: {data!r}\n\n"
                + "".join(traceback.format_exception(exc)))
            print(f"\n=== NEW CRASH {sig} (saved {out / name}.bin)", file=sys.stderr, flush=True)

    return wrapped


def fuzz_main(target: str, test: TestOneInput) -> None:
    """Run ``test`` under libFuzzer with this process's command line."""
    import atheris

    argv = list(sys.argv)
    dictionary = FUZZ_DIR / "dicts" / f"{target}.dict"
    if dictionary.exists() and not any(a.startswith("-dict=") for a in argv[1:]):
        argv.insert(1, f"-dict={dictionary}")
    keep = os.environ.get(KEEP_GOING_ENV)
    entry = _keep_going(target, test, Path(keep)) if keep else test
    atheris.Setup(argv, entry)
    atheris.Fuzz()
