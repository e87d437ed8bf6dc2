"""The firmware emulated: the four boards, their I²C bus, UART, EEPROM, injected faults and the
emulator's settings. Importing the package imports none of its modules."""
