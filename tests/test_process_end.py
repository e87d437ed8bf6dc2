"""The end of an ``armbench`` process (``bench/workers/process_end.py``) and of its worker
processes (``bench/workers/worker_process.py``): no interpreter teardown, and nothing an ordinary
exit does for the user lost. Real processes: the program in a child interpreter, a real spawned
pool."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

from conftest import packaged_limits_with

from armbench.bench.workers import worker_process
from armbench.bench.workers.blas_threads import BLAS_THREAD_VARIABLES
from armbench.bench.workers.collector_pace import YOUNG_ALLOCATIONS

WAIT_S = 300.0
"""Upper bound of a child process's life here under load (each takes a second or so alone)."""

STARTUP = """
[suites.startup-recovery]
trials = 4
wear_duration_s = 0.0
"""
"""A short start-up recovery run: four power cuts, two for each worker."""


def _python(code: str, cwd: Path,
            env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=cwd, text=True,
                          capture_output=True, timeout=WAIT_S, env=env)


def test_the_status_the_output_and_the_exit_handlers_are_kept(tmp_path: Path) -> None:
    """Unflushed output reaches the reader, the at-exit handlers run (after what the process
    printed), and the status is the one given."""
    done = _python("""
        import atexit, sys
        from armbench.bench.workers.process_end import end_process
        atexit.register(lambda: print("handler ran"))
        print("unflushed", end="")
        print("on stderr", end="", file=sys.stderr)
        end_process(3)
        """, tmp_path)
    assert done.returncode == 3, done.stderr
    assert done.stdout == "unflushedhandler ran\n"
    assert done.stderr == "on stderr"


def test_a_thread_still_at_work_is_waited_for(tmp_path: Path) -> None:
    """A thread that is not a daemon finishes its work before the process ends, as with an
    ordinary exit."""
    done = _python("""
        import threading, time
        from armbench.bench.workers.process_end import end_process
        def work():
            time.sleep(0.3)
            print("thread done", flush=True)
        threading.Thread(target=work).start()
        end_process(4)
        """, tmp_path)
    assert done.returncode == 4, done.stderr
    assert done.stdout == "thread done\n"


def test_a_run_in_workers_ends_with_nothing_left_behind(tmp_path: Path) -> None:
    """``python -m armbench run`` with two workers: its status and record, and none of its
    semaphores left for multiprocessing's resource tracker to warn about."""
    config = packaged_limits_with(tmp_path / "short.toml", STARTUP)
    out = tmp_path / "run"
    done = subprocess.run([sys.executable, "-m", "armbench", "run", "startup-recovery", "--config",
                           str(config), "--out", str(out), "--workers", "2", "-q"], cwd=tmp_path,
                          text=True, capture_output=True, timeout=WAIT_S)
    assert done.returncode == 0, done.stderr
    assert "verdict pass" in done.stdout
    assert (out / "report.html").is_file() and (out / "results.json").is_file()
    assert "leaked" not in done.stderr and "resource_tracker" not in done.stderr, done.stderr


def _note_at_exit(path: str) -> int:
    """In a worker: at its exit, ``path`` is written (a handler registered after it started)."""
    import atexit
    import os

    atexit.register(lambda: Path(path).write_text("ran"))
    return os.getpid()


def test_a_worker_let_go_ends_with_status_0_after_its_own_handlers(tmp_path: Path) -> None:
    """A parked pool let go and waited for: its worker ended with status 0, and the at-exit
    handler a job registered in it ran first."""
    pool = worker_process.new_pool(1)
    note = tmp_path / "note"
    pool.submit(_note_at_exit, str(note)).result(timeout=WAIT_S)
    processes = list(pool._processes.values())
    worker_process.park(pool, 1)
    worker_process.let_go_workers(wait=True)
    assert [p.exitcode for p in processes] == [0]
    assert note.read_text() == "ran"


def test_a_pool_no_run_took_is_stopped_not_waited_for(tmp_path: Path) -> None:
    """A refused run's prestarted pool: its workers, still importing what a trial needs, are
    stopped (SIGTERM) when it is let go; a pool a run took is not (above: status 0). The
    program refusing a run (its pool parked, then let go at its end) prints its one-line error
    and nothing of the stopped workers."""
    worker_process.let_go_workers(wait=True)  # a pool an earlier test parked here is not taken
    worker_process.prestart(2, ("armbench.fakes.firmware.arm_emulator",))
    prestarted = worker_process._prestarted
    assert prestarted is not None
    processes = list(prestarted[2]._processes.values())
    worker_process.let_go_workers(wait=True)
    assert [p.exitcode for p in processes] == [-signal.SIGTERM] * 2
    done = subprocess.run([sys.executable, "-m", "armbench", "run", "--config",
                           str(tmp_path / "missing.toml"), "--out", str(tmp_path / "run")],
                          cwd=tmp_path, text=True, capture_output=True, timeout=WAIT_S)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"armbench run: error: limits file: '{tmp_path / 'missing.toml'}' does not exist"]


def test_the_program_and_its_workers_collect_at_armbenchs_pace(tmp_path: Path) -> None:
    """The ``armbench`` program and its spawned workers collect the youngest generation every
    ``YOUNG_ALLOCATIONS`` allocations, the older generations' ratios kept; a process that only
    imports armbench keeps CPython's pace (a child interpreter: this one is the tests', paced
    by ``conftest.py``)."""
    done = _python("""
        import gc
        import armbench, armbench.cli.main as cli
        from armbench.bench.workers import worker_process
        print(*gc.get_threshold())
        def main():
            print(*gc.get_threshold())
            pool = worker_process.new_pool(1)
            print(*pool.submit(gc.get_threshold).result(timeout=300))
            pool.shutdown()
            return 0
        cli.main = main
        cli.program()
    """, tmp_path)
    assert done.returncode == 0, done.stderr
    imported, program, worker = (tuple(map(int, line.split()))
                                 for line in done.stdout.splitlines())
    assert imported[0] != YOUNG_ALLOCATIONS  # CPython's own (700 in 3.11)
    assert program == worker == (YOUNG_ALLOCATIONS, *imported[1:])


def test_the_program_and_its_workers_run_one_blas_thread(tmp_path: Path) -> None:
    """The ``armbench`` program and its spawned workers ask OpenBLAS for one thread: numpy and
    scipy loaded in the program start no thread of theirs (Linux counts them); a process that
    only imports armbench keeps the environment it had; a count the user set wins."""
    code = """
        import os, sys
        import armbench, armbench.cli.main as cli
        from armbench.bench.workers import worker_process
        print(os.environ.get("OPENBLAS_NUM_THREADS"))
        def main():
            import numpy, scipy.linalg
            tasks = len(os.listdir("/proc/self/task")) if sys.platform == "linux" else 1
            pool = worker_process.new_pool(1)
            worker = pool.submit(os.getenv, "OPENBLAS_NUM_THREADS").result(timeout=300)
            pool.shutdown()
            print(os.environ.get("OPENBLAS_NUM_THREADS"), tasks, worker)
            return 0
        cli.main = main
        cli.program()
    """
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    done = _python(code, tmp_path, env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["None", "1", "1", "1"]
    done = _python(code, tmp_path, {**env, "OMP_NUM_THREADS": "2"})
    assert done.returncode == 0, done.stderr
    assert done.stdout.split()[:2] == ["None", "None"]
    assert done.stdout.split()[-1] == "None"
