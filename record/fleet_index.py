"""``fleet.json``: the index of a fleet run (``armbench run --port P1 --port P2 ...``), written by
the runner and read by the fleet page, defined once for both: each arm's name (its folder in the
run directory), port, verdict, exit status and the error that ended it early."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from armbench.drivers.model.user_files import MAX_JSON_BYTES, FileRefused, read_regular_file
from armbench.record import RecordError, atomic_write_bytes

__all__ = ["FLEET_FILE", "FLEET_SCHEMA", "FleetArm", "FleetIndex", "is_fleet", "read_fleet_index",
           "write_fleet_index"]

#: The fleet's index inside the run directory.
FLEET_FILE = "fleet.json"
FLEET_SCHEMA = "armbench-fleet/1"


@dataclass(frozen=True, slots=True)
class FleetArm:
    """One arm of a fleet run; ``verdict`` and ``exit_status`` are None while it runs (or when it
    never began)."""

    name: str
    port: str
    verdict: str | None = None
    exit_status: int | None = None
    error: str | None = None


@dataclass(frozen=True, slots=True)
class FleetIndex:
    """A fleet run: its id, its arms in ``--port`` order, its exit status (None while running)."""

    fleet_id: str
    arms: tuple[FleetArm, ...]
    exit_status: int | None = None


def is_fleet(directory: str | Path) -> bool:
    """Whether ``directory`` is the run directory of a fleet (it holds ``fleet.json``)."""
    return (Path(directory) / FLEET_FILE).is_file()


def write_fleet_index(out_dir: Path, index: FleetIndex) -> None:
    """Write ``out_dir/fleet.json`` atomically."""
    data: dict[str, Any] = {
        "schema": FLEET_SCHEMA, "fleet_id": index.fleet_id, "exit_status": index.exit_status,
        "arms": [{"name": a.name, "port": a.port, "verdict": a.verdict,
                  "exit_status": a.exit_status, "error": a.error} for a in index.arms]}
    atomic_write_bytes(out_dir / FLEET_FILE, (json.dumps(data, indent=1) + "\n").encode())


def _opt(d: dict[str, Any], key: str, kind: type, where: str) -> Any:
    value = d.get(key)
    if value is not None and (not isinstance(value, kind) or isinstance(value, bool)):
        raise RecordError(f"{where}.{key}", f"is not a {kind.__name__}")
    return value


def read_fleet_index(directory: Path) -> FleetIndex:
    """The index of the fleet run in ``directory``; :class:`RecordError` naming the field when it
    is missing or malformed."""
    path = directory / FLEET_FILE
    try:
        data = json.loads(read_regular_file(path, "a fleet.json", MAX_JSON_BYTES))
    except (FileRefused, ValueError, RecursionError) as exc:
        raise RecordError(str(path), f"cannot be read: {exc}") from None
    if not isinstance(data, dict) or data.get("schema") != FLEET_SCHEMA:
        raise RecordError(f"{path}.schema", f"is not {FLEET_SCHEMA!r}")
    arms_data = data.get("arms")
    if not isinstance(arms_data, list):
        raise RecordError(f"{path}.arms", "is not a list")
    arms: list[FleetArm] = []
    for k, a in enumerate(arms_data):
        where = f"{path}.arms[{k}]"
        if not isinstance(a, dict):
            raise RecordError(where, "is not an object")
        name, port = a.get("name"), a.get("port")
        if not isinstance(name, str) or not name or "/" in name or name in (".", ".."):
            raise RecordError(f"{where}.name", "is not an arm folder's name")
        if not isinstance(port, str):
            raise RecordError(f"{where}.port", "is not a string")
        arms.append(FleetArm(name, port, _opt(a, "verdict", str, where),
                             _opt(a, "exit_status", int, where), _opt(a, "error", str, where)))
    fleet_id = data.get("fleet_id")
    if not isinstance(fleet_id, str):
        raise RecordError(f"{path}.fleet_id", "is not a string")
    return FleetIndex(fleet_id, tuple(arms), _opt(data, "exit_status", int, str(path)))

