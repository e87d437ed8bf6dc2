"""Run every atheris harness in turn for a fixed time; exit 1 if any of them crashed.

    python fuzz/run_all.py                          # each target 60 s (tox -e fuzz does this)
    python fuzz/run_all.py -max_total_time=300      # any libFuzzer flag is passed to every target
    python fuzz/run_all.py --targets framer,telnet --workdir runs/fuzz

``differential`` (``fuzz_differential.py``: the firmware in simavr against the emulator) is not an
atheris target; it gets the same time budget and its saved divergences count as crashes.

Per target the fuzzer writes new inputs to ``WORKDIR/<target>/corpus`` (the committed seeds in
``fuzz/corpus/<target>`` are read, never written), crash/timeout/OOM reproducers to
``WORKDIR/<target>/`` and its log to ``WORKDIR/<target>.log``. The summary gives executions,
seconds, coverage (libFuzzer's ``cov``/``ft``) and crashes per target.

``--keep-going`` (long campaigns): exceptions do not stop a target; the first input of each new
crash signature is saved to ``WORKDIR/crashes/<target>/`` and counted (see ``_harness.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

FUZZ_DIR = Path(__file__).resolve().parent
TARGETS = ("framer", "telnet", "config", "emulator_uart", "differential")
#: Not atheris targets: their own loop, given the time budget (``-max_total_time``) and a work
#: folder; their summary line is the last JSON line of their log.
OWN_LOOP = ("differential",)
DEFAULT_FLAGS = {"-max_total_time": "60", "-rss_limit_mb": "512", "-timeout": "30",
                 "-print_final_stats": "1"}


@dataclass
class Result:
    target: str
    returncode: int
    runs: int | None
    seconds: float
    cov: int | None
    ft: int | None
    corpus: str | None
    exec_s: int | None
    crashes: list[str]

    @property
    def failed(self) -> bool:
        return self.returncode != 0 or bool(self.crashes)


_STAT = re.compile(r"cov: (\d+) ft: (\d+) corp: (\S+).*?exec/s: (\d+)")
_DONE = re.compile(r"Done (\d+) runs in (\d+) second")
_FINAL_RUNS = re.compile(r"stat::number_of_executed_units: (\d+)")


def parse_log(text: str) -> tuple[int | None, int | None, int | None, str | None, int | None]:
    """(runs, cov, ft, corpus, exec/s) from a libFuzzer log (the last status line wins)."""
    cov = ft = exec_s = runs = None
    corpus = None
    for m in _STAT.finditer(text):
        cov, ft, corpus, exec_s = int(m[1]), int(m[2]), m[3], int(m[4])
    for m in _DONE.finditer(text):
        runs = int(m[1])
    for m in _FINAL_RUNS.finditer(text):
        runs = int(m[1])
    return runs, cov, ft, corpus, exec_s


def run_own_loop(target: str, flags: list[str], workdir: Path) -> Result:
    """A target with a loop of its own (``fuzz_differential.py``): the time budget passed on,
    the divergences it saved counted as crashes."""
    out = workdir / target
    budget = next((f.split("=", 1)[1] for f in flags if f.startswith("-max_total_time=")),
                  DEFAULT_FLAGS["-max_total_time"])
    cmd = [sys.executable, str(FUZZ_DIR / f"fuzz_{target}.py"), f"-max_total_time={budget}",
           "--workdir", str(out)]
    log = workdir / f"{target}.log"
    print(f"--- {target}: {' '.join(cmd)}", flush=True)
    t0 = time.monotonic()
    with log.open("w") as fh:
        rc = subprocess.call(cmd, stdout=fh, stderr=subprocess.STDOUT)
    seconds = time.monotonic() - t0
    text = log.read_text(errors="replace")
    final: dict[str, object] = {}
    for line in text.splitlines():
        if line.startswith("{"):
            final = json.loads(line)
    crashes = sorted(str(p) for p in (out / "divergences").glob("*.session")) \
        if (out / "divergences").is_dir() else []
    if rc != 0:
        print(text[-4000:], flush=True)
    sessions = final.get("sessions")
    runs = sessions if isinstance(sessions, int) else None
    return Result(target, rc, runs, seconds, None, None, str(final.get("corpus", "?")),
                  round(runs / seconds) if runs and seconds else None, crashes)


def run_target(target: str, flags: list[str], workdir: Path, keep_going: bool) -> Result:
    if target in OWN_LOOP:
        return run_own_loop(target, flags, workdir)
    out = workdir / target
    corpus = out / "corpus"
    corpus.mkdir(parents=True, exist_ok=True)
    given = {f.split("=", 1)[0] for f in flags}
    full = [f"{k}={v}" for k, v in DEFAULT_FLAGS.items() if k not in given] + flags
    cmd = [sys.executable, str(FUZZ_DIR / f"fuzz_{target}.py"), *full,
           f"-artifact_prefix={out}/", str(corpus), str(FUZZ_DIR / "corpus" / target)]
    env = dict(os.environ)
    env.pop("ARMBENCH_FUZZ_KEEP_GOING", None)
    if keep_going:
        env["ARMBENCH_FUZZ_KEEP_GOING"] = str(workdir / "crashes")
    log = workdir / f"{target}.log"
    print(f"--- {target}: {' '.join(cmd)}", flush=True)
    t0 = time.monotonic()
    with log.open("w") as fh:
        rc = subprocess.call(cmd, stdout=fh, stderr=subprocess.STDOUT, env=env)
    seconds = time.monotonic() - t0
    text = log.read_text(errors="replace")
    runs, cov, ft, corp, exec_s = parse_log(text)
    crashes = sorted(str(p) for p in out.iterdir()
                     if p.name.startswith(("crash-", "timeout-", "oom-", "leak-")))
    if keep_going and (workdir / "crashes" / target).exists():
        crashes += sorted(str(p) for p in (workdir / "crashes" / target).glob("*.bin"))
    if rc != 0:
        print(text[-4000:], flush=True)
    return Result(target, rc, runs, seconds, cov, ft, corp, exec_s, crashes)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--targets", default=",".join(TARGETS),
                        help=f"comma-separated subset of {', '.join(TARGETS)}")
    parser.add_argument("--workdir", type=Path, default=None,
                        help="where corpora, logs and crashes go (default: a temporary folder)")
    parser.add_argument("--keep-going", action="store_true",
                        help="record every distinct crash instead of stopping at the first")
    args, flags = parser.parse_known_args(argv)
    targets = [t.strip() for t in args.targets.split(",") if t.strip()]
    unknown = [t for t in targets if t not in TARGETS]
    if unknown:
        parser.error(f"unknown targets: {', '.join(unknown)}")
    bad = [f for f in flags if not f.startswith("-") or f.startswith("--")]
    if bad:
        parser.error(f"not a libFuzzer flag: {' '.join(bad)}")
    workdir = args.workdir or Path(tempfile.mkdtemp(prefix="armbench-fuzz-"))
    workdir.mkdir(parents=True, exist_ok=True)
    results = [run_target(t, flags, workdir, args.keep_going) for t in targets]

    print(f"\nfuzzing summary (work dir {workdir})")
    print(f"{'target':<14} {'result':<7} {'execs':>10} {'secs':>6} {'exec/s':>7} {'cov':>5} "
          f"{'ft':>6} {'corpus':>10} crashes")
    for r in results:
        print(f"{r.target:<14} {'FAIL' if r.failed else 'ok':<7} {r.runs or '?':>10} "
              f"{r.seconds:>6.0f} {r.exec_s or '?':>7} {r.cov or '?':>5} {r.ft or '?':>6} "
              f"{r.corpus or '?':>10} {len(r.crashes)}")
        for c in r.crashes:
            print(f"    {c}")
    return 1 if any(r.failed for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
