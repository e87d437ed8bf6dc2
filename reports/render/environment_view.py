"""The run's environment as the report shows it: what was tested (the unit under test, its code,
the target), where and how it ran (the CI job, armbench's own revision), the robot settings in
short, and the faults injected into the emulator."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from armbench.record import RunRecord
from armbench.reports.render.views import FaultRow, num, text

__all__ = ["dut_rows", "environment_rows", "fault_rows", "settings_summary"]


def dut_rows(record: RunRecord) -> list[tuple[str, str]]:
    """What was tested: the unit under test (name, serial, firmware and host commits, its free
    facts), the kind of target and whether the run had a truth source, and the CI job."""
    env = record.environment
    dut = env.dut
    rows = [("unit under test", dut.label() if dut else "not named (armbench run --dut)")]
    rows += [(key.removeprefix("meta.").replace("_", " "), value) for key, value in dut.items()
             if key not in ("name", "serial")]
    truth = (f"truth: {env.truth_source}" if env.truth_source is not None
             else "no reference instrument")
    rows.append(("target", f"{env.kind} ({truth})"))
    if env.ci is not None:
        rows += [(f"CI {key.replace('_', ' ')}", value) for key, value in env.ci.items()]
    return rows


def environment_rows(record: RunRecord) -> list[tuple[str, str]]:
    env = record.environment
    limits = "-" if env.config_path is None else env.config_path
    if env.limits_spec_version:
        limits += f" ({env.limits_spec_version})"
    return [
        ("run id", record.run_id),
        ("created (UTC)", record.created),
        ("resumed", ", ".join(record.resumed) or "never"),
        *dut_rows(record),
        ("armbench version", env.armbench_version),
        ("armbench's own git revision", env.git_revision),
        ("port", env.port or "-"),
        ("seed", "-" if env.seed is None else str(env.seed)),
        ("limits file", limits),
        ("Python", env.python),
        ("platform", env.platform),
    ]


def settings_summary(settings: Mapping[str, Any]) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    for key, value in settings.items():
        if key == "geometry" and isinstance(value, Mapping):
            parts = []
            for k, v in value.items():
                n = num(v)
                if n is not None and k.endswith("_m"):
                    parts.append(f"{k[:-2]} {n * 1000:g} mm")
                else:
                    parts.append(f"{k} {text(v, 30)}")
            out.append(("geometry", ", ".join(parts)))
        elif key == "serial" and isinstance(value, Mapping):
            baud, bits = value.get("baudrate"), value.get("bytesize")
            parity, stop = value.get("parity"), value.get("stopbits")
            out.append(("serial", f"{text(baud)} baud, {text(bits)}{text(parity)}"
                                  f"{text(stop)}"))
        elif key == "joints" and isinstance(value, Mapping):
            for jname, j in value.items():
                if not isinstance(j, Mapping):
                    out.append((f"joint {jname}", text(j)))
                    continue
                lo, hi = num(j.get("lower_deg")), num(j.get("upper_deg"))
                gear, micro = num(j.get("gear_ratio")), num(j.get("microsteps"))
                addr = j.get("i2c_address")
                bits = []
                if lo is not None and hi is not None:
                    bits.append(f"{lo:.4g}° … {hi:.4g}°")
                if gear is not None:
                    bits.append(f"gear {gear:g}:1")
                if micro is not None:
                    bits.append(f"{micro:g} microsteps")
                if isinstance(addr, int) and not isinstance(addr, bool):
                    bits.append(f"I²C 0x{addr:02x}")
                else:
                    bits.append("I²C master")
                out.append((f"joint {jname}", ", ".join(bits)))
        else:
            out.append((str(key), text(value, 120)))
    return out


def fault_rows(record: RunRecord) -> list[FaultRow]:
    rows = []
    for f in record.environment.faults:
        details = ", ".join(f"{k}={text(v, 80)}" for k, v in f.items()
                            if k != "kind" and v is not None)
        rows.append(FaultRow(kind=text(f.get("kind", "?"), 80), details=details or "-"))
    return rows
