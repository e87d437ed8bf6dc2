"""The emulator's share of the trials' CPU: how much of a trial's work is the emulated arm's own,
and how much the bench's (driver, suites, capture), for the trials of one ``armbench run``.

    python scripts/emulator_share.py [--repeats N] [RUN OPTIONS...]

Each repeat is a fresh process that runs ``armbench run --workers 2`` with the run options given
(none: the default run) and keeps the trial jobs it sends to its workers. It then measures each
job again itself, as a worker does (its attempts, each on a fresh virtual-time loop; the job's
CPU as ``armbench perf`` counts a worker's), and watches the emulator each attempt makes: the
CPU from its construction to its close, and what the bench did to it at its loop times (the
host's bytes, power cuts and restores, board resets, stalls, EEPROM erasures). Each watched
emulator is then replayed: a fresh one with the same settings and faults, the same calls at the
same times, no host (as ``armbench perf`` runs the bare emulator). A replay is **faithful** when
the emulator ends with the same counters as in the trial
(:meth:`~armbench.fakes.firmware.arm_emulator.ArmEmulator.stats`: main loops, commands, bytes,
I²C transactions, EEPROM writes): the same arm doing the same work, so the trial's CPU less the
replay's is the bench's. Prints a table per repeat (suite and trial kind: trials, robot
seconds, the jobs' CPU, the CPU while their emulators ran, the replays' CPU, the jobs' over the
replays', faithful replays), then the totals' least and mean over the repeats; exits 1 when a
replay was not faithful.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import statistics
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from child_figures import child_figures

#: The emulator's methods through which a bench changes what the arm does (the host's bytes and
#: the bench's hands on the arm), recorded and replayed; besides them, an EEPROM of the arm
#: erased (an operator re-referencing the joints, ``EmulatorPower.re_reference``) is recorded
#: as the call ``"erase"`` with the joint's index.
ACTIONS = ("host_write", "power_on", "power_off", "reset_board", "set_stalled")
ERASE = "erase"


@dataclass
class Watched:
    """One emulator of a trial: how it was made, what was done to it and when (seconds after its
    start), what it cost and how it ended."""

    group: str
    args: tuple[Any, ...]
    calls: list[tuple[float, str, tuple[Any, ...], dict[str, Any]]] = field(default_factory=list)
    cpu0_s: float = 0.0
    start_s: float | None = None
    recording: bool = False
    end_s: float | None = None
    cpu_s: float | None = None
    stats: dict[str, Any] | None = None


def _loop_s() -> float:
    return asyncio.get_running_loop().time()


@contextlib.contextmanager
def watching(group: str) -> Iterator[list[Watched]]:
    """Within the block every emulator made is watched (``group`` names the trials making them);
    yields the list the watched emulators are appended to. The emulator's and the EEPROM's
    classes are patched for the block and restored after it."""
    from armbench.fakes.firmware.arm_emulator import ArmEmulator
    from armbench.fakes.firmware.eeprom import Eeprom

    saved = [(cls, name, cls.__dict__[name]) for cls, names in (
        (ArmEmulator, ("__init__", "start", "close", *ACTIONS)), (Eeprom, ("erase",)))
        for name in names]
    watched: list[Watched] = []
    init, start, close = ArmEmulator.__init__, ArmEmulator.start, ArmEmulator.close
    erase = Eeprom.erase

    def watched_init(self: ArmEmulator, *args: Any, **kwargs: Any) -> None:
        w = Watched(group, (args, kwargs), cpu0_s=time.thread_time())
        init(self, *args, **kwargs)
        self._watched = w  # type: ignore[attr-defined]
        for k, eeprom in enumerate(self.eeproms):
            eeprom._watched = (w, k)  # type: ignore[attr-defined]
        watched.append(w)

    def watched_erase(self: Eeprom) -> None:
        w, k = getattr(self, "_watched", (None, 0))
        if w is not None and w.recording:
            assert w.start_s is not None
            w.calls.append((_loop_s() - w.start_s, ERASE, (k,), {}))
        erase(self)

    async def watched_start(self: ArmEmulator) -> None:
        w: Watched | None = getattr(self, "_watched", None)
        if w is not None and w.start_s is None:
            w.start_s = _loop_s()
            await start(self)
            w.recording = True  # after the power-up of start(), which the replay's start() does
            return
        await start(self)

    async def watched_close(self: ArmEmulator) -> None:
        w: Watched | None = getattr(self, "_watched", None)
        if w is not None and w.recording and w.end_s is None:
            w.recording = False
            w.end_s = _loop_s()
            w.stats = self.stats().to_json()
            w.cpu_s = time.thread_time() - w.cpu0_s
        await close(self)

    def recorder(name: str) -> Callable[..., Any]:
        method = getattr(ArmEmulator, name)

        def recorded(self: ArmEmulator, *args: Any, **kwargs: Any) -> Any:
            w: Watched | None = getattr(self, "_watched", None)
            if w is not None and w.recording:
                assert w.start_s is not None
                w.calls.append((_loop_s() - w.start_s, name, args, kwargs))
            return method(self, *args, **kwargs)
        return recorded

    for name in ACTIONS:
        setattr(ArmEmulator, name, recorder(name))
    Eeprom.erase = watched_erase  # type: ignore[method-assign]
    ArmEmulator.__init__ = watched_init  # type: ignore[method-assign]
    ArmEmulator.start = watched_start  # type: ignore[method-assign]
    ArmEmulator.close = watched_close  # type: ignore[method-assign]
    try:
        yield watched
    finally:
        for cls, name, original in saved:
            setattr(cls, name, original)


async def _replay(w: Watched, make: Callable[..., Any]) -> tuple[float, dict[str, Any]]:
    cpu0 = time.thread_time()
    args, kwargs = w.args
    emulator = make(*args, **kwargs)
    emulator.attach_host(lambda data: None)
    await emulator.start()
    t0 = _loop_s()
    for at_s, name, call_args, call_kwargs in w.calls:
        if t0 + at_s > _loop_s():
            await asyncio.sleep(t0 + at_s - _loop_s())
        if name == ERASE:
            emulator.eeproms[call_args[0]].erase()
        else:
            getattr(emulator, name)(*call_args, **call_kwargs)
    assert w.end_s is not None and w.start_s is not None
    rest = t0 + (w.end_s - w.start_s) - _loop_s()
    if rest > 0:
        await asyncio.sleep(rest)
    stats = emulator.stats().to_json()
    cpu = time.thread_time() - cpu0
    await emulator.close()
    return cpu, stats


def replay(w: Watched, make: Callable[..., Any]) -> tuple[float, bool]:
    """Replay ``w`` into a fresh emulator made by ``make`` (with ``w``'s arguments) on a fresh
    virtual-time loop: its CPU seconds, and whether it ended as the watched one did."""
    from armbench.fakes.clock.vclock import run_virtual

    cpu, stats = run_virtual(_replay(w, make))
    return cpu, stats == w.stats


def child(out_dir: str, options: list[str]) -> int:
    """One run in this process (two workers), its trial jobs kept as they are sent out; then
    each job measured again here as a worker measures it (its attempts, each on a fresh
    virtual-time loop), its emulator watched and replayed, and one JSON line of the groups'
    figures printed. Returns the run's exit status."""
    from armbench.bench.runner.parallel import ParallelTrials, TrialJob, run_attempts
    from armbench.bench.workers.blas_threads import one_blas_thread
    from armbench.bench.workers.collector_pace import pace_collector
    from armbench.cli.main import main
    from armbench.fakes.firmware.arm_emulator import ArmEmulator

    jobs: dict[tuple[str, int, int], TrialJob] = {}
    make_job = ParallelTrials._job

    def kept(self: ParallelTrials, ps: Any, index: int, attempt: int) -> TrialJob:
        job = make_job(self, ps, index, attempt)
        jobs.setdefault((ps.name, index, attempt), job)
        return job

    ParallelTrials._job = kept  # type: ignore[method-assign]
    pace_collector()  # as the armbench program and its workers do
    one_blas_thread()
    status = main(["run", "-q", "--workers", "2", "--out", out_dir, *options])
    groups: dict[str, dict[str, float]] = {}
    for job in jobs.values():
        kind = job.params.get("kind")
        name = f"{job.suite.name}/{kind}" if isinstance(kind, str) else job.suite.name
        with watching(name) as watched:
            results = run_attempts(job)
        g = groups.setdefault(name, {"trials": 0, "robot_s": 0.0, "trial_cpu_s": 0.0,
                                     "emulator_cpu_s": 0.0, "replay_cpu_s": 0.0,
                                     "emulators": 0, "faithful": 0})
        g["trials"] += 1
        g["robot_s"] += sum(r.trial.duration_s for r in results)
        g["trial_cpu_s"] += sum(r.worker_cpu_s for r in results)
        for w in watched:
            if w.end_s is None or w.start_s is None or w.cpu_s is None:
                continue
            cpu, same = replay(w, ArmEmulator)
            g["emulators"] += 1
            g["emulator_cpu_s"] += w.cpu_s
            g["replay_cpu_s"] += cpu
            g["faithful"] += int(same)
    print(json.dumps(groups), flush=True)
    return status


def one_run(options: list[str]) -> dict[str, dict[str, float]]:
    """The groups' figures of one watched run with ``options``, in a fresh process."""
    groups: dict[str, dict[str, float]] = child_figures(sys.executable, __file__, options,
                                                        timeout_s=1800)
    return groups


def table(groups: dict[str, dict[str, float]]) -> tuple[list[str], dict[str, float]]:
    """The lines of one run's table, and its totals."""
    keys = ("trials", "robot_s", "trial_cpu_s", "emulator_cpu_s", "replay_cpu_s", "emulators",
            "faithful")
    total = {k: sum(g[k] for g in groups.values()) for k in keys}
    lines = [f"{'suite/kind':24s} {'trials':>6s} {'robot s':>8s} {'trial CPU s':>11s} "
             f"{'emulator s':>10s} {'replay s':>8s} {'ratio':>5s} {'faithful':>8s}"]
    for name, g in [*sorted(groups.items()), ("all", total)]:
        ratio = g["trial_cpu_s"] / g["replay_cpu_s"] if g["replay_cpu_s"] > 0 else float("nan")
        lines.append(f"{name:24s} {g['trials']:6.0f} {g['robot_s']:8.1f} {g['trial_cpu_s']:11.3f} "
                     f"{g['emulator_cpu_s']:10.3f} {g['replay_cpu_s']:8.3f} {ratio:5.2f} "
                     f"{g['faithful']:.0f}/{g['emulators']:.0f}")
    return lines, total


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if args[:1] == ["--child"]:
        return child(args[1], args[2:])
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=1, help="watched runs, each in a fresh "
                                                               "process")
    ns, options = parser.parse_known_args(args)
    totals: list[dict[str, float]] = []
    unfaithful = 0
    for k in range(max(1, ns.repeats)):
        lines, total = table(one_run(options))
        print(f"run {k + 1}:", *lines, sep="\n", flush=True)
        totals.append(total)
        unfaithful += int(total["emulators"] - total["faithful"])
    for key in ("trial_cpu_s", "emulator_cpu_s", "replay_cpu_s"):
        values = [t[key] for t in totals]
        print(f"{key}: least {min(values):.3f} s, mean {statistics.mean(values):.3f} s over "
              f"{len(values)} runs")
    ratios = [t["trial_cpu_s"] / t["replay_cpu_s"] for t in totals if t["replay_cpu_s"] > 0]
    if ratios:
        print(f"trial CPU over replay CPU: mean {statistics.mean(ratios):.2f}")
    if unfaithful:
        print(f"{unfaithful} replays did not end as their trial's emulator did: their CPU is "
              "not the same work")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
