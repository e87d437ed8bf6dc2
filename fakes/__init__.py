"""The emulated arm: the firmware's four boards, their bus, UART and servers, and virtual time.

Light on purpose: importing it imports none of its modules.
"""

if __name__ != "armbench.fakes":  # the checkout's folder imported by its bare name: a second copy
    raise ImportError(f"{__name__!r} installs as armbench.fakes: import it by that name")

