"""What a run ran on and when: the :class:`Environment` (versions, port, settings, seed, faults,
limits file), the git revision, and the run's wall-clock labels and id."""

from __future__ import annotations

import importlib.metadata
import platform
import secrets
import subprocess
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from armbench.drivers.settings import RobotSettings
from armbench.record.fields import _get, _int, _list, _obj, _opt_str, _str
from armbench.record.limits import LimitsConfig
from armbench.record.shapes import EnvironmentJson

__all__ = ["Environment", "capture_environment", "git_revision", "new_run_id", "utc_timestamp"]


def utc_timestamp() -> str:
    """Now, as an ISO 8601 UTC label to the second (wall clock: a label, not a measurement)."""
    return datetime.now(UTC).isoformat(timespec="seconds")


def new_run_id() -> str:
    """A fresh run id: UTC time plus random hex, e.g. ``"20240501T120301Z-3f9a2c"``."""
    return f"{datetime.now(UTC):%Y%m%dT%H%M%SZ}-{secrets.token_hex(3)}"

@dataclass(frozen=True, slots=True)
class Environment:
    """What the run ran on and with: versions, port, robot settings, seed, injected faults and the
    limits file. ``settings`` is :meth:`RobotSettings.to_mapping` (units in the keys)."""

    armbench_version: str
    git_revision: str
    python: str
    platform: str
    port: str | None
    settings: Mapping[str, Any]
    seed: int | None
    faults: tuple[Mapping[str, Any], ...]
    limits_spec_version: str | None
    config_path: str | None
    truth_source: str | None = None
    """The reference instrument the run measured the arm's truth with (the emulator's ground
    truth, a tracker plug-in), None where the figures rest on the arm's encoders alone."""

    def to_json(self) -> EnvironmentJson:
        """The JSON object of this environment."""
        return {
            "armbench_version": self.armbench_version,
            "git_revision": self.git_revision,
            "python": self.python,
            "platform": self.platform,
            "port": self.port,
            "seed": self.seed,
            "limits_spec_version": self.limits_spec_version,
            "config_path": self.config_path,
            "truth_source": self.truth_source,
            "faults": [dict(f) for f in self.faults],
            "settings": dict(self.settings),
        }

    @classmethod
    def from_json(cls, data: object, where: str) -> Environment:
        """Parse an environment object; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)

        def text(key: str) -> str:
            return _str(_get(d, key, where), f"{where}.{key}")

        def opt_text(key: str) -> str | None:
            return _opt_str(_get(d, key, where), f"{where}.{key}")

        seed = _get(d, "seed", where)
        faults = _list(_get(d, "faults", where), f"{where}.faults")
        return cls(
            armbench_version=text("armbench_version"),
            git_revision=text("git_revision"),
            python=text("python"),
            platform=text("platform"),
            port=opt_text("port"),
            settings=_obj(_get(d, "settings", where), f"{where}.settings"),
            seed=None if seed is None else _int(seed, f"{where}.seed"),
            faults=tuple(_obj(f, f"{where}.faults[{i}]") for i, f in enumerate(faults)),
            limits_spec_version=opt_text("limits_spec_version"),
            config_path=opt_text("config_path"),
            truth_source=_opt_str(d.get("truth_source"), f"{where}.truth_source"),
        )


def git_revision() -> str:
    """``git rev-parse HEAD`` of the armbench checkout, or ``"unknown"`` (not a checkout, no git,
    git failing or hanging)."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=Path(__file__).resolve().parent,
            capture_output=True, text=True, timeout=5.0, check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    rev = out.stdout.strip()
    return rev or "unknown"


def _armbench_version() -> str:
    try:
        return importlib.metadata.version("armbench")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def capture_environment(
    *,
    port: str | None = None,
    settings: RobotSettings | None = None,
    seed: int | None = None,
    faults: Iterable[Mapping[str, Any]] = (),
    limits: LimitsConfig | None = None,
    truth_source: str | None = None,
) -> Environment:
    """The environment of this process: armbench version (package metadata), git revision,
    Python and platform, plus what the run was given. ``settings`` None records the defaults;
    ``faults`` are plain mappings (``dataclasses.asdict`` of each fault)."""
    return Environment(
        armbench_version=_armbench_version(),
        git_revision=git_revision(),
        python=platform.python_version(),
        platform=platform.platform(),
        port=port,
        settings=(settings or RobotSettings()).to_mapping(),
        seed=seed,
        faults=tuple(dict(f) for f in faults),
        limits_spec_version=None if limits is None else limits.spec_version,
        config_path=None if limits is None else limits.path,
        truth_source=truth_source,
    )

