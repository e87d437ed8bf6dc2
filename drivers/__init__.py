"""Host side of armbench: the sans-I/O protocol codec, the robot model, kinematics, transports and
the asyncio driver (``armbench.drivers.host.arm``).

Light on purpose: importing it imports none of its modules, so the emulator, which shares the codec
and the robot model, pulls in only what it uses. The public API is re-exported by ``armbench``.
"""

if __name__ != "armbench.drivers":  # the checkout's folder imported by its bare name: a second copy
    raise ImportError(f"{__name__!r} installs as armbench.drivers: import it by that name")

