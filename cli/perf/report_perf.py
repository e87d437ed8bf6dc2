"""Report rendering: seconds to render the report of a big default run, and the page's size.

The workload is a synthetic record shaped like a long default run (:func:`write_big_run`): the
paper's square path, two paper-style and two coordinated runs of 5 000 samples each (20 000
samples with reported and true positions), ISO 9283 repeatability with 30 cycles of the five poses
at three speeds, 20 start-up recovery trials, and a traffic capture of about 90 000 frames beside
it. ``report.render_s`` is the best of a few renders in a warm process (matplotlib imported), from
``results.json`` on disk to ``report.html`` on disk; its bound is the 5 s target.
``report.size_bytes`` is the page's size against the 3 MB target.
"""

from __future__ import annotations

import json
import math
import random
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from armbench.bench.suites.accuracy_contract import ACCURACY
from armbench.bench.suites.repeatability_contract import REPEATABILITY
from armbench.bench.suites.startup_contract import STARTUP
from armbench.cli.perf import Figure, PerfOptions
from armbench.drivers.model.settings import RobotSettings
from armbench.metrics import (
    error_summary,
    iso_cube_poses,
    path_errors,
    pose_accuracy,
    pose_repeatability,
    sample_polyline,
    square_yz,
    tracking_errors,
)
from armbench.record import (
    CAPTURE_FILE,
    Environment,
    Measurement,
    RecordWriter,
    RunRecord,
    SuiteRecord,
    Trial,
    judge,
)
from armbench.record.limits import LimitsConfig, parse_limits

__all__ = ["RENDER_BOUND_S", "SIZE_BOUND_BYTES", "big_run_record", "run", "write_big_run"]

#: Target: seconds to render the big default run.
RENDER_BOUND_S = 5.0
#: Target: size of its report.html (bytes).
SIZE_BOUND_BYTES = 3_000_000

_LIMITS: dict[str, Any] = {
    "spec_version": "armbench-limits/1",
    "limits": {
        "accuracy.paper.mean_mm": {"high": 15.0, "unit": "mm"},
        "accuracy.coordinated.mean_mm": {"high": 5.0, "unit": "mm"},
        "accuracy.*.max_mm": {"high": 25.0, "unit": "mm"},
        "repeatability.*.rp_mm": {"high": 2.0, "unit": "mm"},
        "repeatability.*.ap_mm": {"high": 10.0, "unit": "mm"},
        "startup.recovered": {"low": 1, "unit": "bool"},
        "startup.recovery_time_s": {"high": 10.0, "unit": "s"},
        "startup.position_error_mrad": {"high": 2.0, "unit": "mrad"},
        "startup.success_rate_pct": {"low": 100.0, "unit": "%"},
    },
}
_CENTRE = (0.35, 0.0, 0.45)
_SIDE_M = 0.1


def _r(v: Any) -> list[float]:
    return [round(float(x), 6) for x in v]


def _accuracy(cfg: LimitsConfig, rng: np.random.Generator, samples_per_run: int,
              t0: float) -> tuple[SuiteRecord, float]:
    corners = square_yz(_CENTRE, _SIDE_M)
    perimeter = 4 * _SIDE_M
    path = sample_polyline(corners, perimeter / samples_per_run, closed=True)[:samples_per_run]
    suite = SuiteRecord(name="accuracy", version="1", started_s=t0, status="done",
                        params={"centre_m": list(_CENTRE), "side_m": _SIDE_M, "speed_pct": 50,
                                "runs_per_mode": 2})
    now = t0
    index = 0
    means: dict[str, list[float]] = {"paper": [], "coordinated": []}
    for mode, amp_mm in (("paper", 18.0), ("coordinated", 4.5)):
        for run in range(2):
            u = np.linspace(0.0, 4.0, len(path), endpoint=False) % 1.0
            bulge = amp_mm * np.sin(np.pi * u)[:, None] * np.array([[0.6, 0.55, 0.55]])
            true = path + (bulge + rng.normal(0, 0.3, path.shape)) * 1e-3
            reported = true + rng.normal(0.3, 0.2, path.shape) * 1e-3
            t = np.arange(len(path)) * 0.01
            samples = [{"t_s": round(float(ts), 3), "reported_m": _r(rp), "true_m": _r(tp)}
                       for ts, rp, tp in zip(t, reported, true, strict=True)]
            summary = error_summary(path_errors(reported, corners, closed=True))
            report_err = error_summary(tracking_errors(reported, true))
            means[mode].append(summary.mean_mm)
            duration = float(t[-1])
            suite.trials.append(Trial(index, now, duration,
                                      {ACCURACY.style: mode, ACCURACY.lap: run}, samples, [
                judge(ACCURACY.metric(mode, ACCURACY.mean), summary.mean_mm, "mm", cfg),
                judge(ACCURACY.metric(mode, ACCURACY.max), summary.max_mm, "mm", cfg),
                judge(ACCURACY.metric(mode, ACCURACY.belief_mean), report_err.mean_mm, "mm",
                      cfg)]))
            now += duration + 2.0
            index += 1
    suite.measurements = [judge(ACCURACY.metric(mode, ACCURACY.mean), float(np.mean(v)), "mm",
                                cfg) for mode, v in means.items()]
    suite.ended_s = now
    return suite, now


def _repeatability(cfg: LimitsConfig, rng: np.random.Generator, cycles: int,
                   t0: float) -> tuple[SuiteRecord, float]:
    speeds = (25, 50, 100)
    poses = iso_cube_poses((0.35, 0.0, 0.4), 0.2)
    suite = SuiteRecord(name="repeatability", version="1", started_s=t0, status="done",
                        params={"cube_centre_m": [0.35, 0.0, 0.4], "cube_side_m": 0.2,
                                "speeds_pct": list(speeds), "cycles": cycles})
    attained: dict[tuple[int, int], list[list[float]]] = {}
    now = t0
    index = 0
    for k, speed in enumerate(speeds):
        for cycle in range(cycles):
            cycle_time = 4.0 + 150.0 / speed
            samples: list[dict[str, Any]] = []
            for i, commanded in enumerate(poses):
                reported = commanded + rng.normal(0, 0.25 * (1 + k), 3) * 1e-3
                attained.setdefault((k, i), []).append(_r(reported))
                samples.append({"t_s": round(cycle_time * (i + 1) / 5, 3), "pose": f"P{i + 1}",
                                "commanded_m": _r(commanded), "reported_m": _r(reported)})
            suite.trials.append(Trial(index, now, cycle_time,
                                      {REPEATABILITY.kind: REPEATABILITY.pose_kind,
                                       REPEATABILITY.speed: speed, REPEATABILITY.cycle: cycle},
                                      samples,
                                      [judge("repeatability.cycle_time_s", cycle_time, "s",
                                             cfg)]))
            now += cycle_time + 0.5
            index += 1
    ms: list[Measurement] = []
    for k, speed in enumerate(speeds):
        for i, commanded in enumerate(poses):
            pts = np.array(attained[(k, i)])
            pose = f"P{i + 1}"
            ms.append(judge(REPEATABILITY.pose_metric(speed, pose, REPEATABILITY.ap),
                            pose_accuracy(pts, commanded).ap_p_mm, "mm", cfg))
            ms.append(judge(REPEATABILITY.pose_metric(speed, pose, REPEATABILITY.rp),
                            pose_repeatability(pts).rp_mm, "mm", cfg))
    suite.measurements = ms
    suite.ended_s = now
    return suite, now


def _startup(cfg: LimitsConfig, rng: random.Random, trials: int,
             t0: float) -> tuple[SuiteRecord, float]:
    S = STARTUP
    suite = SuiteRecord(name=S.suite, version="1", started_s=t0, status="done",
                        params={"recovery_timeout_s": 15.0})
    now = t0
    recovered = []
    conditions = ("stopped-near", "cw-away-far", "ccw-toward-near")
    for index in range(trials):
        condition = conditions[index % 3]
        ok = index != trials - 3
        rec_s = round(rng.uniform(1.0, 6.0), 2) if ok else 15.0
        err_mrad = round(rng.uniform(0.1, 0.9), 2) if ok else 31.0
        writes = rng.randint(0, 2)
        samples: list[dict[str, Any]] = [
            {"t_s": 1.0, "event": S.ev_fault, "kind": "power_cut", S.condition: condition},
            {"t_s": 1.5, "event": S.ev_power_restore},
            {"t_s": 1.5 + rec_s, "event": S.ev_recovered if ok else S.ev_timeout},
            {"t_s": 1.6 + rec_s, "event": S.ev_outcome, S.f_recovered: ok,
             S.f_failure: None if ok else "position", S.condition: condition,
             S.f_recovery: rec_s if ok else None, S.f_error_mrad: err_mrad}]
        suite.trials.append(Trial(index, now, 1.6 + rec_s,
                                  {S.kind: S.cut_kind, S.condition: condition,
                                   S.joints: [1, 2, 3, 4], S.cut: index}, samples, [
            judge(S.recovered, 1.0 if ok else 0.0, "bool", cfg, better="higher"),
            judge(S.recovery_time, rec_s, "s", cfg),
            judge(S.position_error_mrad, err_mrad, "mrad", cfg),
            judge(S.eeprom_writes, writes, "writes", cfg, better="lower")]))
        recovered.append(ok)
        now += 3.5 + rec_s
    suite.measurements = [judge(S.success_rate, 100.0 * sum(recovered) / len(recovered), "%",
                                cfg, better="higher")]
    suite.ended_s = now
    return suite, now


def big_run_record(*, samples_per_run: int = 5_000, cycles: int = 30,
                   startup_trials: int = 20, seed: int = 1) -> RunRecord:
    """A synthetic record shaped like a long default run (deterministic for a seed)."""
    cfg = parse_limits(_LIMITS, path="bench.toml")
    rng = np.random.default_rng(seed)
    env = Environment(armbench_version="0.1.0", git_revision="0" * 40, python="3.11.7",
                      platform="Linux", port="fake://?seed=1",
                      settings=RobotSettings().to_mapping(),
                      seed=seed, faults=(), limits_spec_version=cfg.spec_version,
                      config_path=cfg.path)
    record = RunRecord(run_id="20240601T000000Z-b16b16", created="2024-06-01T00:00:00+00:00",
                       environment=env, planned_suites=[ACCURACY.suite, REPEATABILITY.suite,
                                                       STARTUP.suite])
    acc, t = _accuracy(cfg, rng, samples_per_run, 0.0)
    rep, t = _repeatability(cfg, rng, cycles, t + 1.0)
    st, _ = _startup(cfg, random.Random(seed), startup_trials, t + 1.0)
    record.suites = {s.name: s for s in (acc, rep, st)}
    return record


def write_big_run(directory: str | Path, *, capture_records: int = 90_000,
                  **kwargs: Any) -> Path:
    """Write :func:`big_run_record` as ``results.json`` in ``directory``, with a
    ``capture.jsonl`` of ``capture_records`` frames beside it (0: none); returns the record's
    path."""
    out = Path(directory)
    writer = RecordWriter(out, big_run_record(**kwargs), overwrite=True)
    if capture_records:
        rng = random.Random(7)
        lines = []
        t = 0.0
        for i in range(capture_records):
            t += 0.01
            error = "bytes outside a frame" if rng.random() < 0.001 else None
            if i % 2 == 0:
                lines.append({"t_s": round(t, 4), "dir": "out",
                              "frame": "$31416,50,31416,50,31416,50,31416,50#", "error": None})
            else:
                lines.append({"t_s": round(t, 4), "dir": "in",
                              "frame": "$0x\\x81" if error else "$31416,31400,31420,31416#",
                              "error": error})
        (out / CAPTURE_FILE).write_text("".join(json.dumps(x) + "\n" for x in lines),
                                           encoding="ascii")
    return writer.path


#: ``--quick``: a smaller run (rougher figures, no warm-up render).
_QUICK = {"samples_per_run": 1_000, "cycles": 5, "startup_trials": 5, "capture_records": 10_000}


def run(options: PerfOptions) -> list[Figure]:
    """Measure the ``report.*`` figures (``--quick``: a smaller run, one cold render)."""
    from armbench.reports import render_report

    repeats = 1 if options.quick else max(1, min(options.repeats, 3))
    workload = "small run (--quick), cold" if options.quick else (
        "big default run: 20 000 accuracy samples, 30 cycles x 5 poses x 3 speeds, 20 start-up "
        "trials, 90 000-frame capture; warm process, best of " + str(repeats))
    with tempfile.TemporaryDirectory(prefix="armbench-perf-report-") as tmp:
        record_path = write_big_run(tmp, **(_QUICK if options.quick else {}))
        out = Path(tmp) / "report.html"
        if not options.quick:
            render_report(record_path, out)  # warm-up: matplotlib's fonts and caches
        best = cpu = math.inf
        for _ in range(repeats):
            start, start_cpu = time.perf_counter(), time.process_time()
            render_report(record_path, out)
            best = min(best, time.perf_counter() - start)
            cpu = min(cpu, time.process_time() - start_cpu)
        size = out.stat().st_size
    return [
        Figure("report.render_s", best, "s", RENDER_BOUND_S, best / RENDER_BOUND_S,
               note=f"{workload}; {cpu:.2f} s of CPU"),
        Figure("report.size_bytes", float(size), "bytes", float(SIZE_BOUND_BYTES),
               size / SIZE_BOUND_BYTES, note="report.html of the same run"),
    ]
