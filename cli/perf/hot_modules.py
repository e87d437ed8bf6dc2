"""The modules a release build compiles with mypyc: the per-reply work of the emulator, the codec
and the driver below its public API.

Importing nothing when loaded, so that ``setup.py`` reads it before anything is installed, and
``armbench perf`` can say which build it measured (``docs/performance.md``).
"""

#: Compiled together as one group; a compiled module sits beside its source and replaces it.
HOT_MODULES = (
    "armbench.drivers.model.protocol",
    "armbench.fakes.firmware.boards",
    "armbench.fakes.firmware.master_board",
    "armbench.fakes.firmware.i2c",
    "armbench.fakes.twin.drive_train",
    "armbench.fakes.twin.joint",
    "armbench.fakes.twin.physics",
    "armbench.fakes.twin.stepper",
    "armbench.fakes.firmware.uart",
    "armbench.drivers.host.replies",
    "armbench.drivers.host.intake",
    "armbench.drivers.host.waiters",
    "armbench.drivers.host.arrival",
    "armbench.drivers.capture.open_block",
    "armbench.fakes.links.handover",
    "armbench.bench.suites.truth_probe",
    "armbench.bench.suites.recovery_judge",
)


def build_name() -> str:
    """``"compiled (mypyc)"`` when every hot module imports from an extension module,
    ``"source"`` when none does, and says which when the build is partial."""
    from importlib import import_module

    compiled = [m for m in HOT_MODULES if not str(import_module(m).__file__).endswith(".py")]
    if len(compiled) == len(HOT_MODULES):
        return "compiled (mypyc)"
    if not compiled:
        return "source"
    return f"partly compiled ({', '.join(compiled)})"
