"""The default ``armbench run`` (every suite on ``fake://``, two workers): its wall time, and
where the run's own process spends it.

``run.default_wall_s`` is the wall time of ``python -m armbench run --out DIR`` in a fresh
process, best of the repeats, and ``run.default_cpu_s`` the CPU time of that process and its
workers. A second fresh process runs the same command with timers around the parts of the run
(``run.phase.*``, wall seconds with the process's CPU seconds in the note, each exclusive of
the others: an import inside the report counts as an import):

* ``imports``: every module loaded (``importlib._bootstrap._find_and_load``);
* ``waiting``: the event loop waiting for the workers' trials (the selector's real waits);
* ``record``: ``results.json`` and its journal (``RecordWriter.write`` / ``add_trial``);
* ``capture``: merging the workers' capture parts into ``capture.mcap`` and closing it;
* ``summaries``: the suites' summaries (``TrialRunner.summarize``, fits and statistics);
* ``report``: ``junit.xml``, ``report.html`` and its attachment to the capture;
* ``other``: the rest of the process after its first line ran (planning, committing trials,
  progress), and ``start``: the wall time before that (interpreter start-up).

``run.serial_s`` is the timed run's wall time outside the trials: the seconds of its process
(interpreter start-up included) during which no worker was measuring a trial (each job's span in
its worker, lined up by ``time.perf_counter``, one clock for the machine's processes): what the
run's own work adds to the trials' time. Work of the run's process while a worker measures
(committing a trial, merging its capture) overlaps the trials and is not in it.

``run.trials_in_workers_s`` is the seconds the trials took inside the workers (sum over both),
``run.trials_per_bare_emulator`` the trials' CPU seconds in the workers over the CPU seconds the
bare emulator (``emulator.cpu_realtime_factor``'s workload) needs for the same robot time
(their wall seconds' ratio in the note), each the best of its repeats: the timed run is run
``repeats`` times (at most three; the phases are the quickest one's), and a moment's
interference belongs to neither. The bare emulator is measured as the trials are: in two
processes at once, as the two workers (two busy processes share what a core has, so one alone
runs faster), for minutes of simulated time each (a few seconds' worth would measure a moment's
interference as much as the emulator). ``run.pool_start_s`` how long a fresh pool of
two spawned workers takes to answer a first job that imports what a trial needs, and
``run.process_start_s`` a bare ``python -c pass``.
"""

from __future__ import annotations

import atexit
import bisect
import collections
import concurrent.futures
import functools
import importlib
import itertools
import json
import multiprocessing
import os
import runpy
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from armbench.cli.perf import Figure, PerfOptions

__all__ = ["PHASES", "run"]

#: Timed parts of the run's process: (phase, module, attribute path).
PHASES = (
    ("imports", "importlib._bootstrap", "_find_and_load"),
    ("waiting", "armbench.fakes.clock.vclock", "_VirtualSelector.select"),
    ("record", "armbench.record.writer", "RecordWriter.write"),
    ("record", "armbench.record.writer", "RecordWriter.add_trial"),
    ("capture", "armbench.bench.runner.capture_parts", "CaptureParts.merge"),
    ("capture", "armbench.bench.runner.capture_parts", "CaptureParts.flush"),
    ("capture", "armbench.bench.runner.capture_parts", "CaptureParts.finish"),
    ("summaries", "armbench.bench.runner.trials", "TrialRunner.summarize"),
    ("report", "armbench.cli.commands.run_files", "write_reports"),
)

#: Simulated seconds of the bare emulator in each of its two processes: long enough (about a
#: second of CPU) that a moment's interference does not decide the yardstick.
BARE_SIM_S = 400.0

#: What a worker imports to measure a trial.
_WORKER_MODULES = ("armbench.bench.runner.parallel", "armbench.bench.suites",
                   "armbench.drivers.host.arm", "armbench.fakes.firmware.arm_emulator")


class _Clock:
    """Exclusive time per phase: entering a phase stops the clock of the one it interrupts."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        """Wall seconds per phase."""
        self.cpu_seconds: dict[str, float] = {}
        """CPU seconds of this process per phase (a busy machine stretches the wall time)."""
        self._stack: list[str] = ["other"]
        self._since = time.perf_counter()
        self._cpu_since = time.process_time()

    def _charge(self) -> None:
        now, cpu = time.perf_counter(), time.process_time()
        top = self._stack[-1]
        self.seconds[top] = self.seconds.get(top, 0.0) + now - self._since
        self.cpu_seconds[top] = self.cpu_seconds.get(top, 0.0) + cpu - self._cpu_since
        self._since, self._cpu_since = now, cpu

    def enter(self, phase: str) -> None:
        self._charge()
        self._stack.append(phase)

    def leave(self) -> None:
        self._charge()
        self._stack.pop()

    def timed(self, phase: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        if getattr(fn, "__code__", None) is not None and fn.__code__.co_flags & 0x80:
            @functools.wraps(fn)
            async def timed_coroutine(*args: Any, **kwargs: Any) -> Any:
                self.enter(phase)  # summaries: no await that suspends inside
                try:
                    return await fn(*args, **kwargs)
                finally:
                    self.leave()
            return timed_coroutine

        @functools.wraps(fn)
        def timed(*args: Any, **kwargs: Any) -> Any:
            self.enter(phase)
            try:
                return fn(*args, **kwargs)
            finally:
                self.leave()
        return timed


def _patch(clock: _Clock) -> list[str]:
    """Put the phase timers in place; the names that were not found (a refactored runner)."""
    missing = []
    for phase, module_name, path in PHASES:
        try:
            owner: Any = importlib.import_module(module_name)
            *parents, name = path.split(".")
            for part in parents:
                owner = getattr(owner, part)
            setattr(owner, name, clock.timed(phase, getattr(owner, name)))
        except (ImportError, AttributeError):
            missing.append(f"{module_name}.{path}")
    return missing


def _trial_jobs() -> list[dict[str, float]]:
    """Every trial job the run commits (its seconds, CPU seconds, start in its worker and robot
    seconds), filled in as the run goes."""
    from armbench.bench.runner import parallel

    jobs: list[dict[str, float]] = []
    commit = parallel.ParallelTrials._commit

    def keep(self: Any, ps: Any, index: int, attempt: int, result: Any, wall_s: float) -> Any:
        jobs.append({"worker_s": result.worker_s, "cpu_s": result.worker_cpu_s,
                     "start_s": result.worker_start_s, "robot_s": result.trial.duration_s})
        return commit(self, ps, index, attempt, result, wall_s)

    parallel.ParallelTrials._commit = keep  # type: ignore[method-assign]
    return jobs


class _CpuTrace:
    """The process's CPU seconds read every ``period_s`` by a thread of its own (bounded):
    how much of it was spent while no trial ran."""

    def __init__(self, period_s: float = 0.05, limit: int = 200_000) -> None:
        self.samples: collections.deque[tuple[float, float]] = collections.deque(maxlen=limit)
        self._stop = threading.Event()
        self._period_s = period_s
        self._thread = threading.Thread(target=self._run, name="cpu-trace", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            self.samples.append((time.perf_counter(), time.process_time()))
            if self._stop.wait(self._period_s):
                return

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        self.samples.append((time.perf_counter(), time.process_time()))

    def cpu_outside(self, spans: list[tuple[float, float]]) -> float:
        """CPU seconds between two samples whose middle none of ``spans`` covers."""
        merged: list[list[float]] = []
        for start, stop in sorted(spans):
            if merged and start <= merged[-1][1]:
                merged[-1][1] = max(merged[-1][1], stop)
            else:
                merged.append([start, stop])
        starts = [m[0] for m in merged]
        total = 0.0
        for (t0, c0), (t1, c1) in itertools.pairwise(self.samples):
            middle = 0.5 * (t0 + t1)
            k = bisect.bisect_right(starts, middle) - 1
            if k < 0 or middle > merged[k][1]:
                total += c1 - c0
        return total


def covered_s(spans: list[tuple[float, float]], begin: float, end: float) -> float:
    """Seconds of [``begin``, ``end``] that at least one of ``spans`` covers."""
    total, reach = 0.0, begin
    for start, stop in sorted(spans):
        start, stop = max(start, reach), min(stop, end)
        if stop > start:
            total += stop - start
            reach = stop
    return total


def child(out_dir: str) -> None:
    """The timed run (in a fresh process): the program as a user runs it (``python -m armbench
    run``), which ends its process; its phases are printed as one JSON line on stdout by an
    at-exit handler, which the program's end runs (after the workers are gone)."""
    begin = time.perf_counter()
    trace = _CpuTrace()
    clock = _Clock()
    clock.enter("setup")
    missing = _patch(clock)
    jobs = _trial_jobs()
    clock.leave()

    def phases() -> None:
        clock.enter("end")
        end = time.perf_counter()
        seconds = {k: v for k, v in clock.seconds.items() if k not in ("setup", "end")}
        cpu = {k: v for k, v in clock.cpu_seconds.items() if k not in ("setup", "end")}
        trace.stop()
        spans = [(j["start_s"], j["start_s"] + j["worker_s"]) for j in jobs]
        print(json.dumps({"phases": seconds, "cpu": cpu, "missing": missing,
                          "worker_s": sum(j["worker_s"] for j in jobs), "jobs": len(jobs),
                          "worker_cpu_s": sum(j["cpu_s"] for j in jobs),
                          "robot_s": sum(j["robot_s"] for j in jobs),
                          "process_s": end - begin, "trials_s": covered_s(spans, begin, end),
                          "serial_cpu_s": trace.cpu_outside(spans)}), flush=True)

    atexit.register(phases)
    sys.argv = ["armbench", "run", "--out", out_dir, "-q"]
    runpy.run_module("armbench", run_name="__main__", alter_sys=True)


def _run_wall(args: list[str], out: Path) -> tuple[float, float, str]:
    """Wall seconds, CPU seconds (with children) and stdout of ``python ARGS``."""
    before = os.times()
    start = time.perf_counter()
    done = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=900,
                          cwd=out.parent)
    wall = time.perf_counter() - start
    after = os.times()
    if done.returncode not in (0, 1):
        raise RuntimeError(f"the default run failed ({done.returncode}): {done.stderr[-500:]}")
    # os.times() counts waited-for children on POSIX; Windows reports them as 0
    cpu = (after.children_user - before.children_user) + (
        after.children_system - before.children_system)
    return wall, cpu, done.stdout


def _warm_worker() -> int:
    for name in _WORKER_MODULES:
        importlib.import_module(name)
    return os.getpid()


def _pool_start_s() -> float:
    from armbench.bench.workers.worker_process import worker_init

    start = time.perf_counter()
    with concurrent.futures.ProcessPoolExecutor(
            2, mp_context=multiprocessing.get_context("spawn"), initializer=worker_init,
            initargs=(os.getpid(),)) as pool:
        futures = [pool.submit(_warm_worker) for _ in range(2)]
        next(concurrent.futures.as_completed(futures)).result()
        elapsed = time.perf_counter() - start
        concurrent.futures.wait(futures)
    return elapsed


def bare_child(sim_s: float, start_at: float) -> None:
    """One process of the bare emulator's yardstick (in a fresh process): ``sim_s`` simulated
    seconds of ``emulator.realtime_factor``'s workload, begun at ``start_at`` on the machine's
    ``perf_counter`` (once the imports are done), its wall and thread CPU seconds printed as one
    JSON line."""
    from armbench.bench.workers.blas_threads import one_blas_thread
    from armbench.bench.workers.collector_pace import pace_collector

    pace_collector()  # as in the trials' workers
    one_blas_thread()  # before numpy loads
    from armbench.cli.perf.emulator_perf import emulate
    from armbench.fakes.clock.vclock import run_virtual

    time.sleep(max(0.0, start_at - time.perf_counter()))
    cpu: list[float] = []
    wall, _ = run_virtual(emulate(sim_s, moving=True, cpu=cpu))
    print(json.dumps({"wall_s": wall, "cpu_s": cpu[0]}), flush=True)


def _bare_emulator(options: PerfOptions) -> tuple[float, float]:
    """The bare emulator's simulated seconds per wall second and per CPU second as the trials
    are measured: in two fresh processes at once, as the run's two workers, for
    :data:`BARE_SIM_S` simulated seconds each (best of the repeats)."""
    sim_s = BARE_SIM_S / 3 if options.quick else BARE_SIM_S
    best_wall = best_cpu = 0.0
    for _ in range(1 if options.quick else 2):
        start_at = time.perf_counter() + 1.5  # after both processes' imports
        procs = [subprocess.Popen(
            [sys.executable, "-c", f"from {__name__} import bare_child; "
                                   f"bare_child({sim_s!r}, {start_at!r})"],
            stdout=subprocess.PIPE, text=True) for _ in range(2)]
        done = []
        try:
            for proc in procs:
                lines = proc.communicate(timeout=600)[0].strip().splitlines()
                if proc.returncode != 0 or not lines:
                    raise RuntimeError(f"the bare emulator's process failed ({proc.returncode})")
                done.append(json.loads(lines[-1]))
        finally:  # a failed or timed-out one leaves no other running
            for proc in procs:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
        best_wall = max(best_wall, 2 * sim_s / sum(d["wall_s"] for d in done))
        best_cpu = max(best_cpu, 2 * sim_s / sum(d["cpu_s"] for d in done))
    return best_wall, best_cpu


def _serial(phases: dict[str, Any], timed_wall: float) -> Figure:
    """``run.serial_s``: the timed run's wall seconds with no trial in a worker."""
    serial = max(0.0, timed_wall - phases["trials_s"])
    own_cpu = sum(phases["cpu"].values())
    return Figure("run.serial_s", serial, "s",
                  note=f"of {timed_wall:.2f} s wall in the timed run's own process, trials in "
                       f"the workers for the other {phases['trials_s']:.2f} s; the process's "
                       f"CPU: {phases['serial_cpu_s']:.2f} s of its {own_cpu:.2f} s with no "
                       "trial in a worker")


def _per_bare_emulator(phases: dict[str, Any], wall_factor: float, cpu_factor: float,
                       runs: int) -> Figure:
    """``run.trials_per_bare_emulator``: the trials' CPU over the bare emulator's for their
    robot time (``phases``: the timed run of ``runs`` whose trials took the least CPU)."""
    robot_s = phases["robot_s"]
    bare_cpu_s, bare_wall_s = robot_s / cpu_factor, robot_s / wall_factor
    return Figure("run.trials_per_bare_emulator", phases["worker_cpu_s"] / bare_cpu_s, "x",
                  note=f"{phases['worker_cpu_s']:.2f} s CPU in the workers for {robot_s:.0f} s "
                       f"of robot time, least of {runs} runs; the bare emulator "
                       f"{bare_cpu_s:.2f} s ({cpu_factor:.0f} sim s/CPU s, two processes at "
                       f"once, best of its runs); wall: {phases['worker_s']:.2f} s "
                       f"against {bare_wall_s:.2f} s, {phases['worker_s'] / bare_wall_s:.2f}x")


def run(options: PerfOptions) -> list[Figure]:
    """Measure the ``run.*`` figures (a few default runs: tens of seconds each)."""
    repeats = 1 if options.quick else max(1, min(options.repeats, 3))
    best_wall, best_cpu = float("inf"), float("inf")
    with tempfile.TemporaryDirectory(prefix="armbench-perf-run-") as tmp:
        for k in range(repeats):
            out = Path(tmp) / f"plain{k}"
            wall, cpu, _ = _run_wall(["-m", "armbench", "run", "--out", str(out), "-q"], out)
            best_wall, best_cpu = min(best_wall, wall), min(best_cpu, cpu)
        timed_runs: list[tuple[float, dict[str, Any]]] = []
        for k in range(repeats):
            out = Path(tmp) / f"timed{k}"
            wall, _, stdout = _run_wall(
                ["-c", f"from {__name__} import child; child({str(out)!r})"], out)
            lines = stdout.strip().splitlines()
            if not lines:
                raise RuntimeError("the timed default run printed no phases")
            timed_runs.append((wall, json.loads(lines[-1])))
    # the phases of the quickest timed run; the trials' CPU of the cheapest, as the bare
    # emulator's is its best: a moment's interference belongs to neither
    timed_wall, phases = min(timed_runs, key=lambda run: run[0])
    cheapest = min((run[1] for run in timed_runs), key=lambda p: float(p["worker_cpu_s"]))
    start = min(_run_wall(["-c", "pass"], Path(tempfile.gettempdir()) / "x")[0]
                for _ in range(3))
    bare_wall_factor, bare_cpu_factor = _bare_emulator(options)
    pool = min(_pool_start_s() for _ in range(2 if options.quick else 3))
    figures = [
        Figure("run.default_wall_s", best_wall, "s",
               note="armbench run --out DIR: every suite on fake://, two workers; best of "
                    f"{repeats}"),
        _serial(phases, timed_wall),
        Figure("run.trials_in_workers_s", phases["worker_s"], "s",
               note=f"{phases['jobs']} trial jobs, seconds inside the workers (both added up)"),
        _per_bare_emulator(cheapest, bare_wall_factor, bare_cpu_factor, len(timed_runs)),
        Figure("run.pool_start_s", pool, "s",
               note="two spawned workers: first answer to a job importing what a trial needs"),
        Figure("run.process_start_s", start, "s", note="python -c pass"),
    ]
    if sys.platform != "win32":  # Windows counts no CPU time of finished children
        figures.insert(1, Figure("run.default_cpu_s", best_cpu, "s",
                                 note="CPU of the run and its workers"))
    timed = phases["phases"]
    accounted = sum(timed.values())
    timed["start"] = max(0.0, timed_wall - accounted)
    order = ("start", "imports", "waiting", "record", "capture", "summaries", "report", "other")
    cpu = phases["cpu"]
    for name in order:
        note = f"of {timed_wall:.2f} s wall in the timed run's own process" if name == "start" \
            else f"{cpu.get(name, 0.0):.2f} s CPU"
        figures.append(Figure(f"run.phase.{name}_s", timed.get(name, 0.0), "s", note=note))
    if phases["missing"]:
        figures.append(Figure("run.phase.untimed", float(len(phases["missing"])), "parts",
                              note="not found: " + ", ".join(phases["missing"])))
    return figures
