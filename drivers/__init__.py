"""Host side of armbench: the sans-I/O protocol codec, the robot model, kinematics, transports and
the asyncio driver (``armbench.drivers.arm``).

Light on purpose: importing it imports none of its modules, so the emulator, which shares the codec
and the robot model, pulls in only what it uses. The public API is re-exported by ``armbench``.
"""
