"""What a run ran on and when: the :class:`Environment` (versions, port, settings, seed, faults,
limits file, the unit under test, the CI job, the target's kind), armbench's own git revision,
and the run's wall-clock labels and id."""

from __future__ import annotations

import importlib.metadata
import platform
import secrets
import subprocess
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from armbench.drivers.model.settings import RobotSettings
from armbench.record.ci_run import CiRun
from armbench.record.dut import Dut
from armbench.record.fields import _get, _int, _list, _obj, _opt_str, _str
from armbench.record.limits import LimitsConfig
from armbench.record.shapes import EnvironmentJson

__all__ = ["NOT_A_CHECKOUT", "Environment", "capture_environment", "git_revision", "new_run_id",
           "port_kind", "utc_timestamp"]

#: :func:`git_revision` of an armbench that is not a git checkout (installed from a wheel).
NOT_A_CHECKOUT = "not a checkout"


def utc_timestamp() -> str:
    """Now, as an ISO 8601 UTC label to the millisecond (wall clock: a label, not a
    measurement). Finer than the second, so two runs started in one second keep their order."""
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def new_run_id() -> str:
    """A fresh run id: UTC time plus random hex, e.g. ``"20240501T120301Z-3f9a2c"``."""
    return f"{datetime.now(UTC):%Y%m%dT%H%M%SZ}-{secrets.token_hex(3)}"

def port_kind(port: str | None) -> str:
    """The kind of target a port string names: its URL scheme (``fake``, ``avr``, ``socket``,
    ``rfc2217``, ``labgrid``, a plug-in's), ``serial`` for a device name, ``unknown`` for none:
    what a record written before the kind was recorded is read with."""
    if port is None:
        return "unknown"
    scheme, sep, _ = port.partition("://")
    return scheme.lower() if sep and scheme else "serial"


@dataclass(frozen=True, slots=True)
class Environment:
    """What the run ran on and with: versions, port, robot settings, seed, injected faults and the
    limits file. ``settings`` is :meth:`RobotSettings.to_mapping` (units in the keys).

    ``git_revision`` is armbench's own (:func:`git_revision`), never the arm's firmware: the
    unit under test and its code are ``dut``. ``ci`` is the CI job the run was part of;
    ``target_kind`` the kind of target the port named (:func:`port_kind`), None in records
    written before it was kept."""

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
    dut: Dut = field(default_factory=Dut)
    ci: CiRun | None = None
    target_kind: str | None = None

    @property
    def kind(self) -> str:
        """The kind of target the run measured: as recorded, else the port's."""
        return self.target_kind if self.target_kind is not None else port_kind(self.port)

    @property
    def declares_truth(self) -> bool:
        """Whether the run had a truth source (``truth_source``)."""
        return self.truth_source is not None

    def to_json(self) -> EnvironmentJson:
        """The JSON object of this environment (``dut``, ``ci`` and ``target`` only when
        known)."""
        data: EnvironmentJson = {
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
        if self.dut:
            data["dut"] = self.dut.to_json()
        if self.ci is not None:
            data["ci"] = self.ci.to_json()
        if self.target_kind is not None:
            data["target"] = {"kind": self.target_kind}
        return data

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
        ci = d.get("ci")  # dut, ci and target: absent from records before issue 37
        target = _obj(d.get("target", {}), f"{where}.target")
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
            truth_source=_truth_source(d, port_kind(opt_text("port")), where),
            dut=Dut.from_json(d.get("dut", {}), f"{where}.dut"),
            ci=None if ci is None else CiRun.from_json(ci, f"{where}.ci"),
            target_kind=_opt_str(target.get("kind"), f"{where}.target.kind"),
        )


def _truth_source(d: Mapping[str, object], kind: str, where: str) -> str | None:
    """The recorded ``truth_source``; a record written before it was kept had one exactly when
    it ran on the emulator (``fake``), the one built-in target with ground truth then."""
    if "truth_source" in d:
        return _opt_str(d["truth_source"], f"{where}.truth_source")
    return "the emulator's ground truth" if kind == "fake" else None


def _git(args: list[str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=5.0,
                          check=False)


def git_revision(module: Path | None = None) -> str:
    """armbench's own revision: ``git rev-parse HEAD`` of the checkout that holds ``module``
    (default: this file) when git tracks it there; :data:`NOT_A_CHECKOUT` when it does not (an
    install from a wheel, even one inside another project's checkout, whose revision is not
    armbench's); ``"unknown"`` when git cannot tell (not installed, failing, hanging)."""
    path = (module or Path(__file__)).resolve()
    try:
        tracked = _git(["ls-files", "--error-unmatch", "--", path.name], path.parent)
        if tracked.returncode == 1 or "not a git repository" in tracked.stderr:
            return NOT_A_CHECKOUT
        head = _git(["rev-parse", "HEAD"], path.parent)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    rev = head.stdout.strip()
    return rev if tracked.returncode == 0 and head.returncode == 0 and rev else "unknown"


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
    dut: Dut | None = None,
    ci: CiRun | None = None,
    target_kind: str | None = None,
) -> Environment:
    """The environment of this process: armbench version (package metadata), its git revision,
    Python and platform, plus what the run was given. ``settings`` None records the defaults;
    ``faults`` are plain mappings (``dataclasses.asdict`` of each fault); ``dut`` None takes
    the limits file's ``[dut]`` table."""
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
        dut=dut if dut is not None else (Dut() if limits is None else limits.dut),
        ci=ci,
        target_kind=target_kind,
    )

