"""The emulated arm: the firmware's four boards, their bus, UART and servers, and virtual time.

Light on purpose: importing it imports none of its modules.
"""
