"""Measure campaign throughput on a local Dask cluster (issue 18's targets): for each worker
count, start a ``distributed.LocalCluster`` (worker processes on loopback, one thread each),
run ``armbench campaign SUITE --samples N`` on it and report trials per second (wall), the
seconds each trial took inside a worker, and the overhead per trial: wall x workers / trials
minus the time inside the worker.

    python scripts/dask_throughput.py --samples 240 --workers 1 2 [--suite startup-recovery]
"""

from __future__ import annotations

import argparse
import io
import os
import re
import tempfile
import time
from pathlib import Path

from distributed import LocalCluster

from armbench.bench.campaign import CampaignOptions, run_campaign

_JOBS = re.compile(r"(\d+) job\(s\) took ([0-9.]+) s in the workers, ([0-9.]+) s of wall")


def measure(suite: str, samples: int, workers: int, seed: int, out: Path) -> dict[str, float]:
    """One campaign on a fresh cluster of ``workers`` processes; its figures."""
    with LocalCluster(n_workers=workers,  # type: ignore[no-untyped-call]  # no annotations
                      threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=":0") as cluster:
        progress = io.StringIO()
        t0 = time.perf_counter()
        outcome = run_campaign(CampaignOptions(suite, samples, seed=seed, out=out,
                                               scheduler=cluster.scheduler_address),
                               progress=progress)
        wall = time.perf_counter() - t0
    m = _JOBS.search(progress.getvalue())
    assert m is not None, progress.getvalue()[-2000:]
    jobs, inside, parallel_wall = int(m[1]), float(m[2]), float(m[3])
    trials = len(outcome.record.suites[suite].trials)
    return {"workers": workers, "trials": trials, "wall_s": wall,
            "trials_per_s": trials / parallel_wall, "inside_ms": 1e3 * inside / jobs,
            "overhead_ms": 1e3 * (parallel_wall * workers - inside) / jobs}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--suite", default="startup-recovery")
    parser.add_argument("--samples", type=int, default=240)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for w in args.workers:
            rows.append(measure(args.suite, args.samples, w, args.seed, Path(tmp) / f"w{w}"))
            r = rows[-1]
            print(f"workers {w}: {r['trials']} trials, {r['wall_s']:.1f} s wall (with start-up), "
                  f"{r['trials_per_s']:.2f} trials/s, {r['inside_ms']:.1f} ms per trial in the "
                  f"worker, overhead {r['overhead_ms']:.1f} ms per trial", flush=True)
    base = rows[0]["trials_per_s"] / rows[0]["workers"]
    for r in rows[1:]:
        print(f"speed-up {r['workers']} workers vs {rows[0]['workers']}: "
              f"{r['trials_per_s'] / rows[0]['trials_per_s']:.2f}x "
              f"(ideal {r['workers'] / rows[0]['workers']:.0f}x; per worker {base:.2f}/s)")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
