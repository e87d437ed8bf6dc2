"""A toy third-party simulator target for ``tests/test_bench_targets.py``: the scheme ``toy://``,
registered as another distribution would (an entry point of ``armbench.transports``), declaring
its capabilities in its query: ``toy://?caps=virtual,fresh,truth``.

Underneath it plays the built-in emulator (it has to speak the protocol), but nothing in armbench
knows the scheme: whatever the bench gives it comes from what it declares. It counts the fresh
arms it was asked for (in this process).
"""

from __future__ import annotations

from typing import ClassVar
from urllib.parse import parse_qs, urlsplit

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import SerialSettings
from armbench.drivers.transports.capabilities import Capabilities, FreshArm, Given
from armbench.fakes.links.fake_transport import FakeTransport

#: The words of ``?caps=`` → the capability each declares.
WORDS = {"virtual": "clock", "fresh": "fresh_per_trial", "parallel": "parallel",
         "truth": "truth", "power": "power", "faults": "faults", "bus": "i2c_bus"}


class ToyTransport(FakeTransport):
    """``toy://?caps=...``: a simulated arm with the capabilities its query names."""

    scheme = "toy"
    fresh_arms: ClassVar[int] = 0
    """Fresh arms made in this process."""

    @classmethod
    def capabilities(cls, port: str) -> Capabilities:
        words = [w for w in parse_qs(urlsplit(port).query).get("caps", [""])[-1].split(",") if w]
        flags: dict[str, object] = {}
        for word in words:
            if word not in WORDS:
                raise ArmbenchError(f"{port}: unknown capability {word!r}")
            flags[WORDS[word]] = "virtual" if word == "virtual" else True
        return Capabilities(**flags)  # type: ignore[arg-type]

    @classmethod
    def query(cls, port: str) -> Given:
        unknown = set(parse_qs(urlsplit(port).query)) - {"caps"}
        if unknown:
            raise ArmbenchError(f"{port}: unknown query parameter {sorted(unknown)[0]!r}")
        return Given()

    @classmethod
    def fresh(cls, port: str, serial: SerialSettings, arm: FreshArm) -> FakeTransport:
        cls.fresh_arms += 1
        return super().fresh(port, serial, FreshArm(arm.robot, arm.seed, arm.faults))

    @classmethod
    def arm_name(cls, port: str) -> str:
        return "toy"
