"""The TCP side of twin-check: where the capture has truth (a tracker's stream, or the truth
joints of an MCAP capture of ``fake://`` read through the arm's own model), how far the twin's
true TCP is from the arm's, while moving and at rest (see
:mod:`armbench.bench.twin_check.check`)."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Any, Final

import numpy as np

from armbench.bench.calibrate.align import Track
from armbench.bench.calibrate.replay import TwinTruth
from armbench.drivers.capture.read import read_attachment, read_joint_states
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.kinematics import tcp_position
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.firmware.emulator_settings import actual_robot

__all__ = ["REST_SPEED_M_S", "REST_WINDOW_S", "arm_tcp_from_capture", "tcp_divergence"]

#: The twin counts as at rest where its TCP moves slower than this (m/s) now and
#: REST_WINDOW_S before and after.
REST_SPEED_M_S: Final = 1e-3
REST_WINDOW_S: Final = 0.05
Vec3 = tuple[float, float, float]


def tcp_divergence(arm_tcp: Sequence[tuple[float, Sequence[float]]], twin: TwinTruth,
                   shift_at: Any, scatter_s: float) -> dict[str, float] | None:
    """RMS and largest distance (mm) between the arm's true TCP (m, at its truth times) and the
    twin's true TCP at the aligned instants (its truth read as a trajectory), and the floor
    (mm): the timing scatter (``scatter_s``: replies and reactions) times the TCP's speed. None
    without truth on both sides, or none inside the twin's replay."""
    if not arm_tcp or len(twin.t_s) < 2:
        return None
    track = Track(np.asarray(twin.t_s), np.column_stack([np.asarray(twin.tcp_m),
                                                         np.zeros(len(twin.t_s))]))
    rows = [(t, p) for t, p in arm_tcp if track.t_s[0] <= t <= track.t_s[-1]]
    if not rows:
        return None
    t = np.asarray([r[0] for r in rows])
    at = t - shift_at(t)
    twin_p = track.at(at)[:, :3]
    d_mm = 1e3 * np.linalg.norm(np.asarray([r[1] for r in rows]) - twin_p, axis=1)
    v = track.speed_at(at)[:, :3]
    floor_mm = 1e3 * math.sqrt(scatter_s ** 2 * float(np.mean(np.sum(v * v, axis=1))))
    out = {"rms_mm": float(np.sqrt(np.mean(d_mm * d_mm))), "max_mm": float(d_mm.max()),
           "floor_mm": floor_mm, "samples": float(len(rows))}
    # at rest (the twin still for REST_WINDOW_S either side): no timing in it, what is left is
    # the model's statics (lengths, offsets, play, sag) and the arm's scatter at rest
    rest = np.ones(len(at), dtype=bool)
    for dt in (-REST_WINDOW_S, 0.0, REST_WINDOW_S):
        speed = np.linalg.norm(track.speed_at(at + dt)[:, :3], axis=1)
        rest &= speed <= REST_SPEED_M_S
    if rest.any():
        out["rest_rms_mm"] = float(np.sqrt(np.mean(d_mm[rest] ** 2)))
        out["rest_samples"] = float(rest.sum())
    return out


#: Bytes of an attached ``results.json`` read for its ``environment``, which a record writes
#: near its start (a long run's record is tens of MB; a bomb's is as large as it claims).
RECORD_HEAD_BYTES: Final = 1 << 20


def _environment(head: bytes) -> Any:
    """The ``environment`` object of a run record of which ``head`` is the start (the whole
    record when it is shorter than :data:`RECORD_HEAD_BYTES`)."""
    text = head.decode("utf-8", "replace")
    if len(head) < RECORD_HEAD_BYTES:
        return json.loads(text)["environment"]
    rest = text[text.index('"environment":') + len('"environment":'):]
    return json.JSONDecoder().raw_decode(rest.lstrip())[0]


def _arm_model(path: str, settings: RobotSettings) -> RobotSettings:
    """The actual robot model of the arm an MCAP capture recorded, as far as the capture says:
    a run's capture of a simulated arm with ground truth (``fake://``) attaches its record, whose
    environment holds the run's settings (every source resolved), from which the arm was built.
    Otherwise the twin's own actual model (then the link lengths and offsets cannot be judged:
    they cancel)."""
    from armbench.drivers.transports.target import target_of

    raw = read_attachment(path, "results.json", RECORD_HEAD_BYTES)
    try:
        env = _environment(raw) if raw is not None else {}
        port = str(env.get("port") or "")
        if not port or not target_of(port).capabilities.truth:
            return actual_robot(settings)
        return actual_robot(RobotSettings.from_mapping(env["settings"]))
    except (ValueError, KeyError, TypeError, AttributeError, OSError, ArmbenchError):
        return actual_robot(settings)


def arm_tcp_from_capture(path: str, settings: RobotSettings) -> list[tuple[float, Vec3]]:
    """The arm's true TCP from an MCAP capture's truth joints, through the arm's actual model
    (:func:`_arm_model`), empty without truth."""
    truth = read_joint_states(path)
    if not truth:
        return []
    p = tcp_position(np.asarray([q for _, q in truth]), _arm_model(path, settings))
    return [(t, (float(x), float(y), float(z))) for (t, _), (x, y, z) in zip(truth, p,
                                                                              strict=True)]
