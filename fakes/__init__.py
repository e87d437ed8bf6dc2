"""The emulated arm: the firmware's four boards, their bus, UART and servers, and virtual time.

Before anything else the package chooses the build of its hot modules (``drivers.compiled``):
compiled, or their source.
"""

from drivers.compiled import build

build()
